//! What the launcher reads of rt-core's configuration (`assets/runtime.toml`): the keys that
//! shape the scenario (`return_home`, `[goal] source`), through the one view of that file
//! that rt-core and the bridge hold too ([`shm_schemas::runtime_view`]), defaults included.
//! rt-core itself validates the whole file, with bounds, when it starts; the launcher reports
//! rt-core's refusal if the file is bad.

pub use shm_schemas::runtime_view::{RuntimeView, RuntimeViewError};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::args::GoalSourceChoice;
    use std::path::Path;

    #[test]
    fn reads_return_home_from_the_shipped_config() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/runtime.toml");
        assert!(RuntimeView::load(&p).unwrap().return_home);
        let off: RuntimeView = toml::from_str("return_home = false\nrate_hz = 250.0").unwrap();
        assert!(!off.return_home);
        assert_eq!(off.goal.source, GoalSourceChoice::Camera);
        let action: RuntimeView = toml::from_str("[goal]\nsource = \"action\"").unwrap();
        assert_eq!(action.goal.source, GoalSourceChoice::Action);
        let bad = toml::from_str::<RuntimeView>("[goal]\nsource = \"both\"").unwrap_err();
        assert!(bad.to_string().contains("source"), "{bad}");
    }
}
