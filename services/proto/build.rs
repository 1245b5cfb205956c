//! Compiles `proto/vint/v1` with a vendored `protoc`, so no system protobuf compiler is needed.
//!
//! The `.proto` files live at the repository root (`proto/`), the one place every language reads
//! them from. `services/proto/proto` is a symbolic link to that directory, so the path below stays
//! inside this crate: `cargo package` follows the link and puts the files themselves in the
//! crate's tarball, and the same build script then builds from a clone and from the tarball.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    // SAFETY: build scripts are single-threaded; the variable is read by prost-build below.
    unsafe { std::env::set_var("PROTOC", protoc) };
    let root = "proto";
    let files = ["vint/v1/types.proto", "vint/v1/jobs.proto", "vint/v1/work.proto"].map(|f| format!("{root}/{f}"));
    for f in &files {
        if !std::path::Path::new(f).is_file() {
            return Err(format!(
                "{f} is missing: services/proto/proto must be the symbolic link to the repository's proto/ \
                 (a checkout without symlink support, e.g. git's core.symlinks=false, leaves a text file)"
            )
            .into());
        }
    }
    tonic_prost_build::configure().compile_protos(&files, &[root.to_string()])?;
    for f in &files {
        println!("cargo:rerun-if-changed={f}");
    }
    Ok(())
}
