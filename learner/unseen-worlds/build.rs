//! Embeds an rpath to libtorch (and the CUDA runtime libraries beside it in the Python
//! environment) into the `unseen-worlds` binary, as `learner/build.rs` does for the learner's,
//! so that it runs without LD_LIBRARY_PATH.
fn main() {
    // torch-sys exports the directory it linked against as DEP_TCH_LIBTORCH_LIB.
    if let Ok(lib) = std::env::var("DEP_TCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
    }
    // Extra directories written by scripts/setup.sh (colon separated).
    println!("cargo:rerun-if-env-changed=FORESIGHT_TORCH_RPATH");
    if let Ok(extra) = std::env::var("FORESIGHT_TORCH_RPATH") {
        for dir in extra.split(':').filter(|d| !d.is_empty()) {
            println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
        }
    }
}
