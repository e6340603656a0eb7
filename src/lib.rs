//! # bevy_soft_tissue
//!
//! Real-time simulation of many soft organs at once, each at its own level of precision:
//! a precise method (tetrahedral FEM or mass-spring-damper) while a tool touches it, and a
//! cheap Green-coordinate cage when it rests (Fernandes e Silva et al., "A Levels-of-Precision
//! Approach for Simulating Multiple Physics-based Soft Tissues").
//!
//! This root package will hold the Bevy plugin (components, systems, assets, inspector). All
//! physics and geometry live in the engine-free [`soft_tissue_core`] crate, re-exported here
//! as [`core`]; today it provides tetrahedral meshes, their file formats, the built-in mesher
//! for the paper's cylinder and organs, and the paper's scenes as data.

pub use soft_tissue_core as core;
