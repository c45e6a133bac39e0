//! The `perception` binary.
fn main() {}
