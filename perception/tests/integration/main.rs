//! perception's integration tests (one binary, one module per concern).

mod accuracy;
mod common;
mod yolo_models;
