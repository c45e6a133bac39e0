//! perception's integration tests (one binary, one module per concern).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod accuracy;
mod common;
mod yolo_int8;
mod yolo_models;
