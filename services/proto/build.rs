//! Compiles `proto/vint/v1` with a vendored `protoc`, so no system protobuf compiler is needed.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    // SAFETY: build scripts are single-threaded; the variable is read by prost-build below.
    unsafe { std::env::set_var("PROTOC", protoc) };
    let root = "../../proto";
    let files = ["vint/v1/types.proto", "vint/v1/jobs.proto", "vint/v1/work.proto"].map(|f| format!("{root}/{f}"));
    tonic_prost_build::configure().compile_protos(&files, &[root.to_string()])?;
    for f in &files {
        println!("cargo:rerun-if-changed={f}");
    }
    Ok(())
}
