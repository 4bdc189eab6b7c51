//! A small 2D drawing toolkit for the per-iteration dashboard and the plots:
//! a raster canvas, bitmap text, colour maps, line plots and the panel layout.
//! Kept dependency-light on purpose: the figures are simple and a plotting or
//! imaging stack would dwarf the rest of the binary.

pub mod canvas;
pub mod colormap;
pub mod dashboard;
pub mod plot;
pub mod text;
