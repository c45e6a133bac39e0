//! The libtorch rpath, shared by the build scripts of the binaries that link libtorch
//! (`learner`, `unseen-worlds`): embeds the directory torch-sys linked against (and the CUDA
//! runtime libraries beside it in the Python environment) so they run without LD_LIBRARY_PATH.

/// Prints the link arguments.
pub fn embed() {
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
