//! The shield on the real twin model ([`TwinModel`]).

use crate::twin_common;

/// The runtime shield's distance (`TwinModel`) covers the table as well as the boxes, so
/// a plan dipping the wrist to the table is refused even without any box in the scene.
#[test]
fn the_shield_model_measures_the_table_too() {
    use rt_core::cycle::shield::ShieldModel;
    use rt_core::cycle::twin_model::TwinModel;
    use twin::{Goal, Scene};

    let model = twin_common::model();
    let task = twin_common::task();
    let mut shield = TwinModel::new(model.clone());
    let empty = Scene::empty(
        0.0,
        Goal {
            center_m: [0.3, 0.0, 0.025],
            size_m: 0.05,
        },
    );
    let start = task.start.joints_rad;
    let high = shield.min_distance_m(&start, &empty);
    assert!(high.is_finite() && high > 0.1, "start posture: {high} m");
    // Shoulder forward, elbow open: the wrist goes down to the table.
    let mut low = start;
    low[1] += 0.9;
    let d_low = shield.min_distance_m(&low, &empty);
    assert!(
        d_low < high - 0.05,
        "lowering the arm must bring it closer to the table: {d_low} vs {high}"
    );
    let tcp = model.tcp_m(&low);
    assert!(
        (d_low - tcp.z).abs() < 0.2,
        "the distance is the table's, near the TCP height {}: {d_low}",
        tcp.z
    );
}
