//! `sqlx::migrate!` embeds the migrations at compile time; cargo does not know that a new file in
//! their directories changes this crate, so it is told here (otherwise an incremental build keeps
//! the old list and a new migration is silently not applied).
//!
//! `migrations` in this crate is a symbolic link to the repository's `migrations/`, so that
//! `cargo package` puts the migrations in the crate's tarball (see `Store::migrator`); cargo
//! follows the link when it looks for changed files.
fn main() {
    println!("cargo:rerun-if-changed=migrations");
}
