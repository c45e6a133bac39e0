//! Foresight's perception.
