//! Embeds an rpath to libtorch into the learner's binaries ([`torch_rpath`]).
#[path = "torch_rpath.rs"]
mod torch_rpath;

fn main() {
    torch_rpath::embed();
}
