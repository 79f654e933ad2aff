// Shared by the build scripts of every crate whose binaries or tests link libtorch (included with `include!`).
//
// * rpath to torch's lib folder, so binaries start without a hand-set LD_LIBRARY_PATH;
// * `--no-as-needed -ltorch_cuda`, because the linker otherwise drops libtorch_cuda (nothing references it
//   directly) and `tch::Cuda::is_available()` is then false even on a GPU machine.
fn link_libtorch() {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    let Ok(libtorch) = std::env::var("LIBTORCH") else {
        println!("cargo:warning=LIBTORCH is not set: run deploy/setup.sh first");
        return;
    };
    let lib = std::path::Path::new(&libtorch).join("lib");
    println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    if lib.join("libtorch_cuda.so").exists() {
        println!("cargo:rustc-link-arg=-L{}", lib.display());
        println!("cargo:rustc-link-arg=-Wl,--no-as-needed");
        println!("cargo:rustc-link-arg=-ltorch_cuda");
        println!("cargo:rustc-link-arg=-Wl,--as-needed");
    }
}
