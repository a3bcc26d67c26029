//! Rendering: the CPU renderer and the image/AOV writers.

pub mod cpu;
pub mod output;

pub use cpu::{render, Frame, RenderOptions};
