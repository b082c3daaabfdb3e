//! The integration tests of the renderer and the command line, in one test binary (one link
//! instead of one per file; they share one GPU device): the `relief` binary end to end (every
//! command, its JSON and its errors), rendering on lavapipe against golden images and CPU
//! references, windows under Xvfb. The GPU-free library has its own (`tests/core`, run by
//! relief-core). `long_flight` and `large_terrain` are binaries of their own: they measure the
//! process's memory.

#[path = "../common/mod.rs"]
mod common;
#[path = "../common/json.rs"]
mod json;

mod cli;
mod convert;
mod device;
mod edge_cases;
mod flight;
mod fly;
mod fuzz_regressions;
mod georef;
mod height_cache;
mod imagery;
mod layouts;
mod mesh_io;
mod mesh_render;
mod meta_nodes;
mod pages;
mod refine;
mod remote;
mod render;
mod shard;
mod vdt_build;
