//! Which intruder kinds a dynamic sweep runs (`sweep --dynamic --kinds all|classic|grown|a,b,…`)
//! and how an episode's kind is chosen. An episode whose turn is a classic kind draws
//! exactly as the dynamic sweep did before issue 42 (the same seed stream, the same draws:
//! `--kinds classic` is that sweep, episode for episode); a grown kind draws from a seed
//! stream of its own ([`IntruderDraw::draw_grown`](super::intruder::IntruderDraw)).

use rand::Rng;
use serde::{Serialize, Serializer};

use super::intruder::IntruderKind;
use crate::sweep::episode_rng;

/// Mixed into the sweep's seed for the choice of an episode's kind.
const KIND_SEED_SALT: u64 = 0x6b19_d5e1_0042_0007;

/// Mixed into the sweep's seed for the grown kinds' draws.
pub(crate) const GROWN_SEED_SALT: u64 = 0x62c7_0e5d_0042_0001;

/// A set of intruder kinds (by their index in [`IntruderKind::ALL`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KindSet(u16);

/// `--kinds` named nothing known.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum KindSetParseError {
    /// An unknown name.
    #[error(
        "unknown intruder kind {0:?}: all, classic, grown, a-e (moving at the start, near miss, \
         parks on the path, takes the goal, appears next to the arm) or a kind's name"
    )]
    Unknown(String),
    /// Nothing named.
    #[error("no intruder kind named")]
    Empty,
}

impl KindSet {
    /// Every kind.
    pub const ALL: KindSet = KindSet((1 << IntruderKind::ALL.len()) - 1);
    /// The four original kinds.
    pub const CLASSIC: KindSet = KindSet(0b1111);
    /// Issue 42's five kinds.
    pub const GROWN: KindSet = KindSet(Self::ALL.0 & !Self::CLASSIC.0);

    fn bit(kind: IntruderKind) -> u16 {
        let i = IntruderKind::ALL
            .iter()
            .position(|k| *k == kind)
            .unwrap_or(0);
        1 << i
    }

    /// Whether `kind` is in the set.
    pub fn contains(self, kind: IntruderKind) -> bool {
        self.0 & Self::bit(kind) != 0
    }

    /// The kinds in the set, in the order of [`IntruderKind::ALL`].
    pub fn kinds(self) -> impl Iterator<Item = IntruderKind> {
        IntruderKind::ALL
            .into_iter()
            .filter(move |k| self.contains(*k))
    }

    /// Parses `all`, `classic`, `grown`, or a comma-separated list of kinds: the letters
    /// `a`–`e` of issue 42 item 7 (moving at the start, near miss, parks on the path, takes
    /// the goal, appears next to the arm) or any kind's [`IntruderKind::name`].
    ///
    /// # Errors
    /// [`KindSetParseError`] on an unknown name or an empty list.
    pub fn parse(text: &str) -> Result<Self, KindSetParseError> {
        let mut set = 0u16;
        for word in text.split(',').map(str::trim).filter(|w| !w.is_empty()) {
            set |= match word {
                "all" => Self::ALL.0,
                "classic" => Self::CLASSIC.0,
                "grown" => Self::GROWN.0,
                _ => {
                    let letter = ["a", "b", "c", "d", "e"].iter().position(|l| *l == word);
                    let kind = match letter {
                        Some(i) => IntruderKind::GROWN[i],
                        None => *IntruderKind::ALL
                            .iter()
                            .find(|k| k.name() == word)
                            .ok_or_else(|| KindSetParseError::Unknown(word.to_owned()))?,
                    };
                    Self::bit(kind)
                }
            };
        }
        if set == 0 {
            return Err(KindSetParseError::Empty);
        }
        Ok(Self(set))
    }
}

impl Default for KindSet {
    fn default() -> Self {
        Self::ALL
    }
}

impl Serialize for KindSet {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.kinds().map(IntruderKind::name))
    }
}

/// An episode's kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum KindChoice {
    /// The classic draw, its kind replaced by this one if given (a subset of the classic
    /// kinds is selected).
    Classic(Option<IntruderKind>),
    /// A grown kind.
    Grown(IntruderKind),
}

/// The kind of episode `index`: each selected kind equally likely; with every classic kind
/// selected, a classic turn is the classic draw itself (its own kind draw included).
pub(crate) fn choose(set: KindSet, seed: u64, index: u64) -> KindChoice {
    let classic: Vec<IntruderKind> = set.kinds().filter(|k| k.is_classic()).collect();
    let grown: Vec<IntruderKind> = set.kinds().filter(|k| !k.is_classic()).collect();
    let all_classic = classic.len() == IntruderKind::CLASSIC.len();
    let n = classic.len() + grown.len();
    if n == 0 || (grown.is_empty() && all_classic) {
        return KindChoice::Classic(None);
    }
    let i = episode_rng(seed ^ KIND_SEED_SALT, index).random_range(0..n);
    match classic.get(i) {
        Some(k) => KindChoice::Classic((!all_classic).then_some(*k)),
        None => KindChoice::Grown(grown[i - classic.len()]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds_parse_by_group_letter_and_name() {
        assert_eq!(KindSet::parse("all"), Ok(KindSet::ALL));
        assert_eq!(KindSet::parse("classic"), Ok(KindSet::CLASSIC));
        assert_eq!(KindSet::parse("a,b,c,d,e"), Ok(KindSet::GROWN));
        assert_eq!(KindSet::parse("classic,grown"), Ok(KindSet::ALL));
        let s = KindSet::parse("cross, takes_goal").unwrap();
        assert_eq!(
            s.kinds().collect::<Vec<_>>(),
            vec![IntruderKind::Cross, IntruderKind::TakesGoal]
        );
        assert!(KindSet::parse("f").is_err());
        assert_eq!(KindSet::parse(" , "), Err(KindSetParseError::Empty));
    }

    #[test]
    fn classic_episodes_keep_their_draw_and_every_selected_kind_comes_up() {
        for i in 0..50 {
            assert_eq!(choose(KindSet::CLASSIC, 1, i), KindChoice::Classic(None));
        }
        let mut seen = std::collections::BTreeSet::new();
        let mut classic = 0;
        for i in 0..900 {
            match choose(KindSet::ALL, 1, i) {
                KindChoice::Classic(None) => classic += 1,
                KindChoice::Classic(Some(k)) => panic!("all kinds: the classic draw, not {k:?}"),
                KindChoice::Grown(k) => {
                    seen.insert(k);
                }
            }
        }
        assert_eq!(seen.len(), 5);
        assert!(
            (300..500).contains(&classic),
            "{classic} of 900, 4/9 expected"
        );
        let one = KindSet::parse("teleport,d").unwrap();
        for i in 0..50 {
            let c = choose(one, 1, i);
            assert!(
                c == KindChoice::Classic(Some(IntruderKind::Teleport))
                    || c == KindChoice::Grown(IntruderKind::TakesGoal),
                "{c:?}"
            );
        }
    }
}
