//! Embeds an rpath to libtorch into the `unseen-worlds` binary, as the learner's build
//! script does ([`torch_rpath`], one file for both).
#[path = "../torch_rpath.rs"]
mod torch_rpath;

fn main() {
    torch_rpath::embed();
}
