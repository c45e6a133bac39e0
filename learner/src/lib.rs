//! Foresight's learner.
