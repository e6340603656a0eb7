//! The one place where the core's `f64` nalgebra vectors meet Bevy's `f32` glam vectors.

use bevy::math::{Quat, Vec3};
use soft_tissue_core::Vec3 as CoreVec3;

/// A core vector as a Bevy vector (rounded to `f32`).
#[inline]
pub fn to_bevy(v: &CoreVec3) -> Vec3 {
    Vec3::new(v.x as f32, v.y as f32, v.z as f32)
}

/// A Bevy vector as a core vector.
#[inline]
pub fn to_core(v: Vec3) -> CoreVec3 {
    CoreVec3::new(v.x as f64, v.y as f64, v.z as f64)
}

/// A Bevy rotation as a core rotation.
#[inline]
pub fn to_core_rotation(q: Quat) -> nalgebra::UnitQuaternion<f64> {
    nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        q.w as f64, q.x as f64, q.y as f64, q.z as f64,
    ))
}
