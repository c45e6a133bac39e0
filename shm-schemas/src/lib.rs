//! The shared-memory contract of Foresight: every payload that crosses a process boundary
//! over iceoryx2, with its schema version, its service name and its validation — and the
//! scene file format that the twin, the simulated arm and the synthetic camera all read.

pub mod scene_file;
