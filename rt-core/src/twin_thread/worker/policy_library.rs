//! [`PolicyLibrary`]: the candidates the lookahead tries, in order — the current policy (the
//! latest received, retrained for one world), then the base (the first received: the
//! bundled generalist, kept when retrained ones replace it).
//!
//! A world the generalist solves is solved again without retraining even after a
//! fine-tune forgot it; retraining is asked for only when every policy fails, once per
//! failing policy and scene (the learner restarts its training on every new request).

/// A candidate of the library.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Candidate {
    /// The latest policy received.
    Current,
    /// The first policy received (the bundled generalist).
    Base,
}

impl Candidate {
    /// The order the lookahead tries them in.
    pub const ORDER: [Candidate; 2] = [Candidate::Current, Candidate::Base];
}

/// The policies the worker holds.
pub struct PolicyLibrary<P, S> {
    current: Option<Box<P>>,
    base: Option<Box<P>>,
    /// The policy and scene of the last retrain request.
    last_retrain: Option<(u64, S)>,
}

impl<P, S: Copy + PartialEq> Default for PolicyLibrary<P, S> {
    fn default() -> Self {
        Self {
            current: None,
            base: None,
            last_retrain: None,
        }
    }
}

impl<P, S: Copy + PartialEq> PolicyLibrary<P, S> {
    /// A new policy becomes the current one. The first one ever received is kept as the
    /// base; any other replaced one is returned (to be dropped off the cycle).
    pub fn receive(&mut self, policy: Box<P>) -> Option<Box<P>> {
        let old = self.current.replace(policy);
        if self.base.is_none() {
            self.base = old;
            None
        } else {
            old
        }
    }

    /// The policy of a candidate.
    pub fn get(&self, c: Candidate) -> Option<&P> {
        match c {
            Candidate::Current => self.current.as_deref(),
            Candidate::Base => self.base.as_deref(),
        }
    }

    /// The current policy.
    pub fn current(&self) -> Option<&P> {
        self.current.as_deref()
    }

    /// The base policy, once another has replaced it as current.
    pub fn base(&self) -> Option<&P> {
        self.base.as_deref()
    }

    /// Whether retraining should be asked for `policy_id` failing in `scene`: true once per
    /// pair (and remembered).
    pub fn should_ask_retrain(&mut self, policy_id: u64, scene: S) -> bool {
        if self.last_retrain == Some((policy_id, scene)) {
            return false;
        }
        self.last_retrain = Some((policy_id, scene));
        true
    }
}
