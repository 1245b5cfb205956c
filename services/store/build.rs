//! `sqlx::migrate!` embeds the migrations at compile time; cargo does not know that a new file in
//! their directories changes this crate, so it is told here (otherwise an incremental build keeps
//! the old list and a new migration is silently not applied).
fn main() {
    println!("cargo:rerun-if-changed=../../migrations");
}
