//! Helpers shared by Foresight's system tests.
