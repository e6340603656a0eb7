//! glTF 2.0 surfaces (`.gltf` with its buffers, or `.glb`): every triangle primitive of every
//! mesh the scene's nodes place, in the scene's frame (each node's transform applied after its
//! children's, as the format defines). The container, the JSON and the accessors are read by
//! the `gltf` crate; buffers come from the GLB binary chunk, `data:` URIs (base64) or, for
//! other URIs, from the caller (files beside the `.gltf`).
//!
//! The scene is the file's default scene, else its first; a file with no scene gives every
//! mesh once, untransformed. Node hierarchies must be trees and a scene's nodes its roots,
//! each listed once (a node under two parents, or a scene root that is also a child or
//! listed twice, is refused: walked as given, it places its meshes more than once). Points
//! and lines are skipped; strips and fans become triangles. Positions must be 32-bit floats
//! (quantized positions are refused with a message).

use std::collections::HashMap;

use base64::Engine;
use gltf::Gltf;
use gltf::buffer::Source;
use gltf::mesh::Mode;
use nalgebra::Matrix4;

use super::obj::SurfaceMesh;
use super::{FormatError, Location};
use crate::Vec3;

/// URIs of the buffers a glTF file keeps outside itself (neither in a GLB chunk nor a
/// `data:` URI), percent-decoded: the files a caller must hand to [`parse_gltf`].
pub fn gltf_external_uris(data: &[u8], name: &str) -> Result<Vec<String>, FormatError> {
    let gltf = open(data, name)?;
    Ok(gltf
        .buffers()
        .filter_map(|b| match b.source() {
            Source::Uri(uri) if !uri.starts_with("data:") => Some(percent_decode(uri)),
            _ => None,
        })
        .collect())
}

/// Parses a glTF or GLB file into one triangle surface. `external` returns the bytes of a
/// buffer kept in another file, by its (percent-decoded) URI; `name` is used in messages
/// (an error of `external` is returned naming `name` and the buffer before it).
pub fn parse_gltf(
    data: &[u8],
    name: &str,
    external: &mut dyn FnMut(&str) -> Result<Vec<u8>, FormatError>,
) -> Result<SurfaceMesh, FormatError> {
    let gltf = open(data, name)?;
    let mut buffers: Vec<Vec<u8>> = Vec::new();
    for buffer in gltf.buffers() {
        let i = buffer.index();
        let bytes = match buffer.source() {
            Source::Bin => gltf.blob.clone().ok_or_else(|| {
                FormatError::unsupported(
                    name,
                    format!("buffer {i} is the GLB binary chunk, but the file has none"),
                )
            })?,
            Source::Uri(uri) if uri.starts_with("data:") => decode_data_uri(uri)
                .map_err(|why| FormatError::unsupported(name, format!("buffer {i}: {why}")))?,
            // The caller's error names the buffer's file; the message names the glTF too.
            Source::Uri(uri) => {
                let file = percent_decode(uri);
                external(&file).map_err(|e| match e {
                    FormatError::Io { file: path, source } => FormatError::Io {
                        file: format!("{name}: buffer {i}: {path}"),
                        source,
                    },
                    e => FormatError::unsupported(name, format!("buffer {i} ({file}): {e}")),
                })?
            }
        };
        if bytes.len() < buffer.length() {
            return Err(FormatError::unsupported(
                name,
                format!(
                    "buffer {i} should hold {} bytes, but has {}",
                    buffer.length(),
                    bytes.len()
                ),
            ));
        }
        buffers.push(bytes);
    }
    let mut out = SurfaceMesh::default();
    let scene = gltf.default_scene().or_else(|| gltf.scenes().next());
    match scene {
        Some(scene) => {
            // The format's node hierarchy is a set of trees (a mesh, not a node, is what
            // several nodes share). A node under two parents is refused: walked as given,
            // a chain of such nodes places its meshes exponentially many times.
            let mut parent_of: Vec<Option<usize>> = vec![None; gltf.nodes().len()];
            for node in gltf.nodes() {
                for child in node.children() {
                    if let Some(first) = parent_of[child.index()].replace(node.index()) {
                        let parents = if first == node.index() {
                            format!("listed twice under node {first}")
                        } else {
                            format!("a child of both node {first} and node {}", node.index())
                        };
                        return Err(FormatError::unsupported(
                            name,
                            format!(
                                "node {} is {parents}; glTF node hierarchies must be trees \
                                 (share the mesh instead)",
                                child.index()
                            ),
                        ));
                    }
                }
            }
            // A scene's nodes must be root nodes, each listed once (glTF 2.0, 3.5.1: "MUST
            // NOT be listed in a node.children array of any node"; scene.nodes has unique
            // items). A root that is also a child is walked from the scene and again from
            // its parent (a chain listed whole as roots, quadratically often).
            let mut listed = vec![false; gltf.nodes().len()];
            for root in scene.nodes() {
                let r = root.index();
                let why = if let Some(parent) = parent_of[r] {
                    format!(
                        "node {r} is a root of scene {} and a child of node {parent}; a glTF \
                         scene's nodes must be root nodes, listed in no node's children",
                        scene.index()
                    )
                } else if std::mem::replace(&mut listed[r], true) {
                    format!(
                        "node {r} is listed twice in scene {}'s nodes; a glTF scene lists \
                         each root node once",
                        scene.index()
                    )
                } else {
                    continue;
                };
                return Err(FormatError::unsupported(name, why));
            }
            // Parents first; a cycle (each node with one parent, which the format also
            // forbids) is refused by the depth bound.
            let mut stack: Vec<(gltf::Node<'_>, Matrix4<f64>, usize)> =
                scene.nodes().map(|n| (n, Matrix4::identity(), 0)).collect();
            let limit = gltf.nodes().len();
            while let Some((node, parent, depth)) = stack.pop() {
                if depth > limit {
                    return Err(FormatError::unsupported(
                        name,
                        format!("node {} is its own ancestor", node.index()),
                    ));
                }
                let local = node.transform().matrix();
                let local = Matrix4::from_fn(|r, c| f64::from(local[c][r]));
                let world = parent * local;
                if !world.iter().all(|v| v.is_finite()) {
                    return Err(FormatError::unsupported(
                        name,
                        format!("node {}: its transform is not finite", node.index()),
                    ));
                }
                if let Some(mesh) = node.mesh() {
                    add_mesh(&mut out, &mesh, &world, &buffers, name)?;
                }
                stack.extend(node.children().map(|c| (c, world, depth + 1)));
            }
        }
        None => {
            for mesh in gltf.meshes() {
                add_mesh(&mut out, &mesh, &Matrix4::identity(), &buffers, name)?;
            }
        }
    }
    if out.triangles.is_empty() {
        return Err(FormatError::unsupported(
            name,
            "the glTF scene places no triangles",
        ));
    }
    Ok(out)
}

fn open(data: &[u8], name: &str) -> Result<Gltf, FormatError> {
    let err = |e: gltf::Error| FormatError::parse(name, Location::File, e.to_string());
    // gltf 1.4.1 subtracts the 12-byte header from the GLB's stated length unchecked (an
    // overflow; found by fuzzing): a shorter stated length is refused here.
    if data.starts_with(b"glTF") {
        let stated = data
            .get(8..12)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        if stated.is_none_or(|n| n < 12) {
            return Err(FormatError::parse(
                name,
                Location::Byte(8),
                format!(
                    "the GLB header states a length of {stated:?} bytes, less than the header's 12"
                ),
            ));
        }
    }
    let gltf = Gltf::from_slice_without_validation(data).map_err(err)?;
    // gltf-json 1.4.1's validation indexes the accessors by a primitive's POSITION before
    // checking that index (found by fuzzing: it panics), so that one is checked first.
    let json = gltf.document.as_json();
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &primitive.attributes {
                if index.value() >= json.accessors.len() {
                    return Err(FormatError::parse(
                        name,
                        Location::File,
                        format!(
                            "mesh {m} primitive {p}: attribute {semantic:?} names accessor {}, \
                             but there are {}",
                            index.value(),
                            json.accessors.len()
                        ),
                    ));
                }
            }
        }
    }
    let Gltf { document, blob } = gltf;
    let document = gltf::Document::from_json(document.into_json()).map_err(err)?;
    Ok(Gltf { document, blob })
}

fn add_mesh(
    out: &mut SurfaceMesh,
    mesh: &gltf::Mesh<'_>,
    world: &Matrix4<f64>,
    buffers: &[Vec<u8>],
    name: &str,
) -> Result<(), FormatError> {
    let mirrored = world.fixed_view::<3, 3>(0, 0).determinant() < 0.0;
    for primitive in mesh.primitives() {
        let at = || match mesh.name() {
            Some(n) => format!(
                "mesh {} ({n:?}) primitive {}",
                mesh.index(),
                primitive.index()
            ),
            None => format!("mesh {} primitive {}", mesh.index(), primitive.index()),
        };
        let mode = primitive.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            continue;
        }
        let err = |why: String| FormatError::unsupported(name, format!("{}: {why}", at()));
        let accessor = primitive
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| err("no POSITION attribute".into()))?;
        if accessor.dimensions() != gltf::accessor::Dimensions::Vec3
            || accessor.data_type() != gltf::accessor::DataType::F32
            || accessor.normalized()
        {
            return Err(err(format!(
                "positions are {:?} of {:?}; only 32-bit float VEC3 positions are read",
                accessor.dimensions(),
                accessor.data_type()
            )));
        }
        let reader = primitive.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
        let positions: Vec<[f32; 3]> = reader
            .read_positions()
            .ok_or_else(|| err("the positions lie outside their buffer".into()))?
            .collect();
        if positions.len() != accessor.count() {
            return Err(err(format!(
                "{} positions read where the accessor says {}",
                positions.len(),
                accessor.count()
            )));
        }
        let indices: Vec<u32> = match primitive.indices() {
            Some(ia) => {
                use gltf::accessor::DataType;
                // (The gltf crate's index reader assumes an unsigned type: checked here.)
                if ia.dimensions() != gltf::accessor::Dimensions::Scalar
                    || !matches!(ia.data_type(), DataType::U8 | DataType::U16 | DataType::U32)
                {
                    return Err(err(format!(
                        "indices are {:?} of {:?}; unsigned integer scalars are read",
                        ia.dimensions(),
                        ia.data_type()
                    )));
                }
                let read: Vec<u32> = reader
                    .read_indices()
                    .ok_or_else(|| err("the indices lie outside their buffer".into()))?
                    .into_u32()
                    .collect();
                if read.len() != ia.count() {
                    return Err(err(format!(
                        "{} indices read where the accessor says {}",
                        read.len(),
                        ia.count()
                    )));
                }
                if let Some((k, &bad)) = read
                    .iter()
                    .enumerate()
                    .find(|&(_, &i)| i as usize >= positions.len())
                {
                    return Err(err(format!(
                        "index {k} is {bad}, but there are {} positions",
                        positions.len()
                    )));
                }
                read
            }
            None => (0..positions.len() as u32).collect(),
        };
        let base = out.positions.len();
        let base32 = u32::try_from(base)
            .ok()
            .filter(|b| b.checked_add(positions.len() as u32).is_some())
            .ok_or_else(|| err("more than 2^32 vertices in all".into()))?;
        for (k, p) in positions.iter().enumerate() {
            let q = world
                * nalgebra::Vector4::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]), 1.0);
            let v = Vec3::new(q.x, q.y, q.z);
            if !v.iter().all(|c| c.is_finite()) {
                return Err(err(format!("position {k} is not finite")));
            }
            out.positions.push(v);
        }
        let mut push = |a: u32, b: u32, c: u32| {
            let t = if mirrored { [a, c, b] } else { [a, b, c] };
            out.triangles.push(t.map(|i| base32 + i));
        };
        match mode {
            Mode::Triangles => {
                for t in indices.chunks_exact(3) {
                    push(t[0], t[1], t[2]);
                }
            }
            Mode::TriangleStrip => {
                for k in 0..indices.len().saturating_sub(2) {
                    let (a, b, c) = (indices[k], indices[k + 1], indices[k + 2]);
                    if k % 2 == 0 {
                        push(a, b, c)
                    } else {
                        push(b, a, c)
                    }
                }
            }
            _ => {
                for k in 1..indices.len().saturating_sub(1) {
                    push(indices[0], indices[k], indices[k + 1]);
                }
            }
        }
    }
    Ok(())
}

/// The bytes of a `data:[<mediatype>][;base64],<data>` URI.
fn decode_data_uri(uri: &str) -> Result<Vec<u8>, String> {
    let (head, body) = uri
        .split_once(',')
        .ok_or_else(|| "a data URI without a comma".to_string())?;
    if head.ends_with(";base64") {
        base64::engine::general_purpose::STANDARD
            .decode(body.trim())
            .map_err(|e| format!("its base64 data URI does not decode: {e}"))
    } else {
        Ok(percent_decode(body).into_bytes())
    }
}

/// `%XX` escapes of a URI replaced by their bytes (anything else kept as it is).
fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        if b[i] == b'%'
            && i + 2 < b.len()
            && let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2]))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Resolves external buffers beside `path` (for [`super::read_surface`]).
pub(super) fn read_beside(data: &[u8], path: &std::path::Path) -> Result<SurfaceMesh, FormatError> {
    let name = path.display().to_string();
    let dir = path.parent().map(|p| p.to_path_buf()).unwrap_or_default();
    let mut cache: HashMap<String, Vec<u8>> = HashMap::new();
    parse_gltf(data, &name, &mut |uri| {
        if let Some(b) = cache.get(uri) {
            return Ok(b.clone());
        }
        let file = dir.join(uri);
        let bytes = std::fs::read(&file).map_err(|e| FormatError::io(&file, e))?;
        cache.insert(uri.to_string(), bytes.clone());
        Ok(bytes)
    })
}
