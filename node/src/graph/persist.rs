//! Map snapshots: a versioned binary file, written atomically.
//!
//! ```text
//! magic "GFMAP\r\n\x1a" | u32 LE version | u64 LE header length | header (JSON: instances,
//! keyframes, counters) | u64 LE payload length | payload (f32 LE Gaussian attributes, instance
//! by instance) | SHA-256 of everything before it
//! ```
//!
//! Saving writes a temporary file next to the target, syncs it and renames it over the target,
//! so a crash mid-write leaves the previous snapshot intact. Loading checks magic, version,
//! lengths and checksum before building anything, so a corrupt or newer file is a clear error
//! and the running map is never touched.

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::fusion::SceneMap;
use super::instance::{FusionParams, Instance};
use crate::frame::Keyframe;
use crate::recon::camera::{Camera, PlumbBob};
use crate::recon::gaussians::Gaussians;
use crate::recon::Rigid;

/// The persistent instance map: where `~/save_map` and `~/load_map` write and read by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapSection {
    /// Snapshot file; `null`: services need an explicit path and nothing is restored.
    pub file: Option<String>,
    /// Load `file` at start when it exists (a corrupt or newer file is logged; the map starts empty).
    pub restore_on_start: bool,
    /// Save the map to `file` when the node stops (Ctrl-C, SIGTERM, end of a run), so a restart
    /// finds what the robot mapped; a failed save is logged and the previous file stays.
    pub save_on_exit: bool,
    /// `save_map` / `load_map` request paths are confined to this directory: a relative path
    /// resolves inside it, and `..` or an absolute path elsewhere is refused. `null`: the
    /// directory of `file`, or the node's working directory without one (`/` allows any path the
    /// node can write: trusted networks only). `file` itself is not confined.
    pub directory: Option<String>,
}

impl MapSection {
    /// The absolute directory request paths are confined to (see `directory`).
    pub fn confining_directory(&self) -> std::path::PathBuf {
        let working = std::env::current_dir().unwrap_or_else(|_| std::path::PathBuf::from("/"));
        let chosen = match (&self.directory, &self.file) {
            (Some(directory), _) => std::path::PathBuf::from(directory),
            (None, Some(file)) => std::path::Path::new(file)
                .parent()
                .map(std::path::Path::to_path_buf)
                .unwrap_or_default(),
            (None, None) => working.clone(),
        };
        if chosen.is_absolute() {
            chosen
        } else {
            working.join(chosen)
        }
    }
}

impl Default for MapSection {
    fn default() -> Self {
        Self {
            file: None,
            restore_on_start: true,
            save_on_exit: true,
            directory: None,
        }
    }
}

pub const MAGIC: &[u8; 8] = b"GFMAP\r\n\x1a";
pub const VERSION: u32 = 1;

#[derive(Debug, thiserror::Error)]
pub enum PersistError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("not a groupforward map (bad magic)")]
    NotAMap,
    #[error("map format version {found} is newer than this build reads ({supported})")]
    NewerVersion { found: u32, supported: u32 },
    #[error("map file is corrupt: {0}")]
    Corrupt(String),
}

#[derive(Debug, Serialize, Deserialize)]
struct Header {
    next_id: u64,
    instances: Vec<InstanceHeader>,
    keyframes: Vec<KeyframeRecord>,
    /// Pairs of instances a window saw as two objects; absent from maps saved before it was kept
    /// (and from maps without any, so their bytes are as before).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    seen_apart: Vec<(String, String)>,
}

#[derive(Debug, Serialize, Deserialize)]
struct InstanceHeader {
    id: String,
    prototype: Vec<f32>,
    prototype_weight: f64,
    confidence: f32,
    observations: u32,
    first_seen_nanos: i64,
    last_seen_nanos: i64,
    /// Absent from maps saved before viewpoints were kept.
    #[serde(default)]
    viewpoint: Option<[f32; 3]>,
    #[serde(default)]
    viewpoint_weight: f32,
    /// Absent from maps saved before the range noise was kept.
    #[serde(default)]
    range_noise_m: f32,
    #[serde(default)]
    range_noise_weight: f32,
    /// Absent from maps saved before it was kept (and from instances without any).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    seen_free: Vec<[f32; 3]>,
    gaussians: usize,
    embedding_dim: usize,
    extra_dim: usize,
}

#[derive(Debug, Serialize, Deserialize)]
struct KeyframeRecord {
    stamp_nanos: i64,
    width: u32,
    height: u32,
    /// fx, fy, cx, cy.
    intrinsics: [f64; 4],
    /// k1, k2, p1, p2, k3.
    distortion: [f64; 5],
    /// x, y, z, w.
    rotation: [f64; 4],
    translation: [f64; 3],
}

fn floats_per_gaussian(embedding_dim: usize, extra_dim: usize) -> usize {
    3 + 1 + 3 + 4 + 3 + embedding_dim + extra_dim
}

/// Serialise `map` to bytes.
pub fn to_bytes(map: &SceneMap) -> Vec<u8> {
    let header = Header {
        next_id: map.next_id,
        seen_apart: map.seen_apart.iter().cloned().collect(),
        instances: map
            .instances
            .iter()
            .map(|i| InstanceHeader {
                id: i.id.clone(),
                prototype: i.prototype.clone(),
                prototype_weight: i.prototype_weight,
                confidence: i.confidence,
                observations: i.observations,
                first_seen_nanos: i.first_seen_nanos,
                last_seen_nanos: i.last_seen_nanos,
                viewpoint: i.viewpoint.map(|v| v.to_array()),
                viewpoint_weight: i.viewpoint_weight,
                range_noise_m: i.range_noise_m,
                range_noise_weight: i.range_noise_weight,
                seen_free: i.seen_free.iter().map(|p| p.to_array()).collect(),
                gaussians: i.gaussians.len(),
                embedding_dim: i.gaussians.embedding_dim,
                extra_dim: i.gaussians.extra_dim,
            })
            .collect(),
        keyframes: map
            .keyframes
            .iter()
            .map(|k| KeyframeRecord {
                stamp_nanos: k.stamp_nanos,
                width: k.camera.width,
                height: k.camera.height,
                intrinsics: [k.camera.fx, k.camera.fy, k.camera.cx, k.camera.cy],
                distortion: [
                    k.camera.distortion.k1,
                    k.camera.distortion.k2,
                    k.camera.distortion.p1,
                    k.camera.distortion.p2,
                    k.camera.distortion.k3,
                ],
                rotation: k.world_from_camera.rotation.to_array(),
                translation: k.world_from_camera.translation.to_array(),
            })
            .collect(),
    };
    // Serialising plain structs of numbers and strings cannot fail.
    let json = serde_json::to_vec(&header).unwrap_or_default();
    let mut payload = Vec::new();
    for instance in &map.instances {
        let g = &instance.gaussians;
        let mut put = |v: f32| payload.extend_from_slice(&v.to_le_bytes());
        for i in 0..g.len() {
            g.means[i].to_array().into_iter().for_each(&mut put);
            put(g.opacities[i]);
            g.scales[i].to_array().into_iter().for_each(&mut put);
            g.rotations[i].to_array().into_iter().for_each(&mut put);
            g.colors[i].to_array().into_iter().for_each(&mut put);
            g.embedding(i).iter().copied().for_each(&mut put);
            g.extra[i * g.extra_dim..(i + 1) * g.extra_dim]
                .iter()
                .copied()
                .for_each(&mut put);
        }
    }
    let mut out = Vec::with_capacity(8 + 4 + 16 + json.len() + payload.len() + 32);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&payload);
    let digest = Sha256::digest(&out);
    out.extend_from_slice(&digest);
    out
}

fn take<'a>(
    bytes: &'a [u8],
    at: &mut usize,
    n: usize,
    what: &str,
) -> Result<&'a [u8], PersistError> {
    let end = at
        .checked_add(n)
        .filter(|&end| end <= bytes.len())
        .ok_or_else(|| PersistError::Corrupt(format!("truncated in the {what}")))?;
    let out = &bytes[*at..end];
    *at = end;
    Ok(out)
}

fn u64_at(bytes: &[u8], at: &mut usize, what: &str) -> Result<u64, PersistError> {
    let raw = take(bytes, at, 8, what)?;
    Ok(u64::from_le_bytes(raw.try_into().unwrap_or([0; 8])))
}

/// Parse a snapshot; `params` are the running configuration's (not stored in the file).
pub fn from_bytes(bytes: &[u8], params: FusionParams) -> Result<SceneMap, PersistError> {
    if bytes.len() < 12 || &bytes[..8] != MAGIC {
        return Err(PersistError::NotAMap);
    }
    let version = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    if version > VERSION {
        return Err(PersistError::NewerVersion {
            found: version,
            supported: VERSION,
        });
    }
    if bytes.len() < 12 + 32 {
        return Err(PersistError::Corrupt("truncated".into()));
    }
    let (body, digest) = bytes.split_at(bytes.len() - 32);
    if Sha256::digest(body).as_slice() != digest {
        return Err(PersistError::Corrupt("checksum mismatch".into()));
    }
    let mut at = 12;
    let header_len = u64_at(body, &mut at, "header length")? as usize;
    let header: Header = serde_json::from_slice(take(body, &mut at, header_len, "header")?)
        .map_err(|e| PersistError::Corrupt(format!("header: {e}")))?;
    let payload_len = u64_at(body, &mut at, "payload length")? as usize;
    let payload = take(body, &mut at, payload_len, "payload")?;
    if at != body.len() {
        return Err(PersistError::Corrupt("trailing bytes".into()));
    }
    let expected: usize = header
        .instances
        .iter()
        .map(|i| i.gaussians * floats_per_gaussian(i.embedding_dim, i.extra_dim) * 4)
        .sum();
    if expected != payload.len() {
        return Err(PersistError::Corrupt(format!(
            "payload holds {} bytes, the header describes {expected}",
            payload.len()
        )));
    }
    let mut floats = payload
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
    let mut next = |n: usize| -> Vec<f32> { floats.by_ref().take(n).collect() };
    let mut instances = Vec::with_capacity(header.instances.len());
    for h in header.instances {
        let mut g = Gaussians::with_dims(h.embedding_dim, h.extra_dim);
        for _ in 0..h.gaussians {
            let mean = next(3);
            let opacity = next(1);
            let scale = next(3);
            let rotation = next(4);
            let color = next(3);
            let embedding = next(h.embedding_dim);
            let extra = next(h.extra_dim);
            g.push(
                Vec3::from_slice(&mean),
                opacity[0],
                Vec3::from_slice(&scale),
                Quat::from_slice(&rotation),
                Vec3::from_slice(&color),
                &embedding,
                &extra,
            );
        }
        g.validate()
            .map_err(|e| PersistError::Corrupt(format!("instance {}: {e}", h.id)))?;
        instances.push(Instance {
            id: h.id,
            gaussians: g,
            prototype: h.prototype,
            prototype_weight: h.prototype_weight,
            confidence: h.confidence,
            observations: h.observations,
            first_seen_nanos: h.first_seen_nanos,
            last_seen_nanos: h.last_seen_nanos,
            viewpoint: h.viewpoint.map(Vec3::from_array).filter(|v| v.is_finite()),
            viewpoint_weight: h.viewpoint_weight,
            range_noise_m: finite_or_zero(h.range_noise_m),
            range_noise_weight: finite_or_zero(h.range_noise_weight),
            seen_free: h
                .seen_free
                .into_iter()
                .map(Vec3::from_array)
                .filter(|p| p.is_finite())
                .collect(),
        });
    }
    let keyframes = header
        .keyframes
        .into_iter()
        .map(|k| {
            let [fx, fy, cx, cy] = k.intrinsics;
            let [k1, k2, p1, p2, k3] = k.distortion;
            let camera = Camera::pinhole(k.width, k.height, fx, fy, cx, cy)
                .map_err(|e| PersistError::Corrupt(format!("keyframe camera: {e}")))?;
            Ok(Keyframe {
                stamp_nanos: k.stamp_nanos,
                camera: Camera {
                    distortion: PlumbBob { k1, k2, p1, p2, k3 },
                    ..camera
                },
                world_from_camera: Rigid::new(
                    glam::DQuat::from_array(k.rotation),
                    glam::DVec3::from_array(k.translation),
                ),
            })
        })
        .collect::<Result<_, PersistError>>()?;
    Ok(SceneMap {
        instances,
        keyframes,
        next_id: header.next_id,
        params,
        seen_apart: header.seen_apart.into_iter().collect(),
    })
}

/// `x` where it is finite and not negative (a noise, a weight), else 0 (none measured).
fn finite_or_zero(x: f32) -> f32 {
    if x.is_finite() {
        x.max(0.0)
    } else {
        0.0
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> PersistError + '_ {
    move |source| PersistError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Write `bytes` to `path` atomically: a temp file in the same directory, synced, then renamed
/// over `path`, and the directory synced (so the rename survives a power cut). A failure at any
/// point (disk full, crash) leaves `path` as it was and removes the temp file; the temp files of
/// a process killed mid-write (`.<name>.<random>.tmp`) are removed by the next save to `path`.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), PersistError> {
    write_atomically_with(path, bytes, |file, bytes| file.write_all(bytes))
}

/// [`write_atomically`] with the write itself supplied (tests use it to fail mid-write).
pub fn write_atomically_with(
    path: &Path,
    bytes: &[u8],
    write: impl FnOnce(&mut std::fs::File, &[u8]) -> std::io::Result<()>,
) -> Result<(), PersistError> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map_or_else(|| "snapshot".into(), |n| n.to_string_lossy().into_owned());
    let prefix = format!(".{name}.");
    remove_stale_temp_files(dir, &prefix);
    let mut temp = tempfile::Builder::new()
        .prefix(&prefix)
        .suffix(TEMP_SUFFIX)
        .tempfile_in(dir)
        .map_err(io(dir))?;
    write(temp.as_file_mut(), bytes).map_err(io(path))?;
    temp.as_file().sync_all().map_err(io(path))?;
    temp.persist(path).map_err(|e| PersistError::Io {
        path: path.to_owned(),
        source: e.error,
    })?;
    // Not every platform lets a directory be synced; the rename itself has happened.
    if let Ok(directory) = std::fs::File::open(dir) {
        let _ = directory.sync_all();
    }
    Ok(())
}

const TEMP_SUFFIX: &str = ".tmp";

/// Remove temp files a writer of this target left when it was killed mid-write (saves to one
/// target are serialised by the node; a second process writing the same file is a misuse, and
/// its rename then fails with an error rather than tearing the snapshot).
fn remove_stale_temp_files(dir: &Path, prefix: &str) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with(prefix) && name.ends_with(TEMP_SUFFIX) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// The map's content hash: SHA-256 of its snapshot bytes (ids, prototypes, every Gaussian,
/// keyframes), the first 16 hex digits. Two runs that built the same map print the same hash.
pub fn content_hash(map: &SceneMap) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(to_bytes(map))
        .iter()
        .take(8)
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Save `map` to `path` atomically.
pub fn save(map: &SceneMap, path: &Path) -> Result<(), PersistError> {
    write_atomically(path, &to_bytes(map))
}

/// Load a snapshot from `path`.
pub fn load(path: &Path, params: FusionParams) -> Result<SceneMap, PersistError> {
    let bytes = std::fs::read(path).map_err(io(path))?;
    from_bytes(&bytes, params)
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    #[test]
    fn map_requests_are_confined_by_default_to_the_snapshot_s_or_the_working_directory() {
        let working = std::env::current_dir().unwrap_or_else(|e| panic!("{e}"));
        let section = |file: Option<&str>, directory: Option<&str>| MapSection {
            file: file.map(str::to_owned),
            directory: directory.map(str::to_owned),
            ..MapSection::default()
        };
        assert_eq!(section(None, None).confining_directory(), working);
        assert_eq!(
            section(Some("/data/maps/robot.gfmap"), None).confining_directory(),
            PathBuf::from("/data/maps")
        );
        assert_eq!(
            section(Some("maps/robot.gfmap"), None).confining_directory(),
            working.join("maps")
        );
        assert_eq!(
            section(Some("robot.gfmap"), None).confining_directory(),
            working
        );
        assert_eq!(
            section(Some("/data/maps/robot.gfmap"), Some("/srv/maps")).confining_directory(),
            PathBuf::from("/srv/maps")
        );
        assert_eq!(
            section(None, Some("/")).confining_directory(),
            PathBuf::from("/")
        );
    }
}
