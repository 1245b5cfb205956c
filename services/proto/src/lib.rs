//! Generated gRPC types and services of `proto/vint/v1`. No hand-written logic lives here.
#![allow(clippy::all, clippy::pedantic)]

pub mod v1 {
    tonic::include_proto!("vint.v1");
}
