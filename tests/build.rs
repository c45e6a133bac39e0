//! Embeds the libtorch rpath into the system tests that link the learner's library
//! (`converged_is_approved`), as the learner's own build script does for its binaries.
#[path = "../learner/torch_rpath.rs"]
mod torch_rpath;

fn main() {
    torch_rpath::embed();
}
