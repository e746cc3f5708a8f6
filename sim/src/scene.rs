//! Scene files (TOML): a room, objects from the library (on the floor or on another object's
//! surface), a camera rig on the robot, a trajectory and the effects to simulate. Unknown keys are
//! errors, so a misspelt key never silently becomes a default.

use std::path::Path;

use glam::{DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::effects::{Effect, Preset};
use crate::library;
use crate::render::{Pinhole, PlacedObject, Scene};

#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("cannot read scene {path}: {reason}")]
    Read { path: String, reason: String },
    #[error("unknown object class `{0}`")]
    UnknownClass(String),
    #[error("object {index} (`{class}`) {reason}")]
    BadObject {
        index: usize,
        class: String,
        reason: String,
    },
    #[error("objects {0} and {1} overlap")]
    Overlap(usize, usize),
    #[error("{0}")]
    Invalid(String),
}

pub type Result<T> = std::result::Result<T, SceneError>;

#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub name: String,
    /// Seeds everything random: effects and random-walk trajectories.
    #[serde(default)]
    pub seed: u64,
    pub room: RoomSpec,
    pub objects: Vec<ObjectSpec>,
    pub cameras: Vec<CameraSpec>,
    pub trajectory: Trajectory,
    /// The effects to simulate, in this order; none by default (the clean render).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub effects: Vec<Effect>,
    /// A named effect set (`clean`, `realistic`, `dropout:<p>`) applied under `effects`: an
    /// effect listed in `effects` replaces the preset's of the same kind.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub effects_preset: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RoomSpec {
    /// Extent along x, y, z (metres); the room spans [0, size].
    pub size: [f64; 3],
    pub floor_color: [f32; 3],
    pub wall_color: [f32; 3],
}

#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSpec {
    pub class: String,
    /// Position of the object's base (x, y), metres, on the floor or on its support's surface.
    pub position: [f64; 2],
    #[serde(default)]
    pub yaw_deg: f64,
    #[serde(default = "unit")]
    pub scale: f64,
    /// Overrides the class colour.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<[f32; 3]>,
    /// Index (in this list, earlier than this object) of the object it stands on; absent: the floor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub on: Option<usize>,
    /// Which surface of the support (0: the first, e.g. a bookshelf's lowest shelf).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub surface: usize,
}

fn unit() -> f64 {
    1.0
}

fn is_zero(value: &usize) -> bool {
    *value == 0
}

#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Also the topic prefix (`/<name>/color/image_raw`) and the frame (`<name>_color_optical_frame`).
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub fov_x_deg: f64,
    /// Position on the robot (`base_link`: x forward, z up), metres.
    pub mount: [f64; 3],
    /// Downward tilt, degrees.
    #[serde(default)]
    pub pitch_deg: f64,
}

#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "snake_case")]
pub enum Trajectory {
    /// The robot circles `center`, facing it.
    Orbit {
        center: [f64; 2],
        radius: f64,
        frames: usize,
        rate_hz: f64,
    },
    /// Straight segments between (x, y, yaw_deg) waypoints.
    Waypoints {
        points: Vec<[f64; 3]>,
        frames_per_segment: usize,
        rate_hz: f64,
    },
    /// A seeded random walk from `start` (x, y, yaw_deg) through free space: constant speed,
    /// heading perturbed by `turn_deg` (standard deviation per frame), turning away from walls and
    /// objects.
    RandomWalk {
        start: [f64; 3],
        frames: usize,
        rate_hz: f64,
        speed: f64,
        turn_deg: f64,
    },
}

/// The robot's pose at one frame: `world_from_base` and the stamp offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotPose {
    pub time_secs: f64,
    pub position: DVec3,
    pub yaw: f64,
}

/// Tolerance for "touching is not overlapping" (metres).
const CONTACT: f64 = 1e-6;

/// Clearance the robot keeps from walls and from objects standing on the floor (metres).
pub const ROBOT_CLEARANCE: f64 = 0.35;

/// Example scenes built into the binary (the files under `sim/scenes/`), by name.
pub const BUILTIN: &[(&str, &str)] = &[
    ("two_chairs", include_str!("../scenes/two_chairs.toml")),
    (
        "office_effects",
        include_str!("../scenes/office_effects.toml"),
    ),
];

impl SceneFile {
    /// The effects to simulate: the preset's (if any) with the listed ones replacing those of the
    /// same kind, then the other listed ones.
    pub fn resolved_effects(&self) -> Result<Vec<Effect>> {
        let Some(name) = &self.effects_preset else {
            return Ok(self.effects.clone());
        };
        let preset = Preset::parse(name).map_err(SceneError::Invalid)?;
        let mut effects: Vec<Effect> = preset
            .effects()
            .into_iter()
            .filter(|e| self.effects.iter().all(|listed| listed.kind() != e.kind()))
            .collect();
        effects.extend(self.effects.iter().cloned());
        Ok(effects)
    }

    /// Replace the scene's effects by a preset's (what `--effects <preset>` does to every scene).
    pub fn apply_preset(&mut self, preset: Preset) {
        self.effects = preset.effects();
        self.effects_preset = None;
    }

    /// A built-in example scene by name.
    pub fn builtin(name: &str) -> Option<Self> {
        let (_, text) = BUILTIN.iter().find(|(n, _)| *n == name)?;
        toml::from_str(text).ok()
    }

    pub fn load(path: &Path) -> Result<Self> {
        let read = |reason: String| SceneError::Read {
            path: path.display().to_string(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| read(e.to_string()))?;
        toml::from_str(&text).map_err(|e| read(e.to_string()))
    }

    /// The scene as TOML, in the form [`SceneFile::load`] reads.
    pub fn to_toml(&self) -> Result<String> {
        toml::to_string(self).map_err(|e| SceneError::Invalid(e.to_string()))
    }

    /// Place the objects: library lookup, inside the room, supported objects on their support's
    /// surface within its clearance, and no two objects' bounds overlapping (except an object and
    /// its support).
    pub fn build(&self) -> Result<Scene> {
        let size = DVec3::from(self.room.size);
        if !(size.min_element() > 0.5 && size.is_finite()) {
            return Err(SceneError::Invalid(format!(
                "room size {:?} is not a room",
                self.room.size
            )));
        }
        if self.cameras.is_empty() {
            return Err(SceneError::Invalid("the robot carries no camera".into()));
        }
        for effect in &self.effects {
            effect.validate().map_err(SceneError::Invalid)?;
        }
        let mut objects: Vec<PlacedObject> = Vec::new();
        let mut bounds: Vec<(DVec3, DVec3)> = Vec::new();
        for (index, spec) in self.objects.iter().enumerate() {
            let class = library::class(&spec.class)
                .ok_or_else(|| SceneError::UnknownClass(spec.class.clone()))?;
            let bad = |reason: String| SceneError::BadObject {
                index,
                class: spec.class.clone(),
                reason,
            };
            if !(spec.scale > 0.0 && spec.scale.is_finite()) {
                return Err(bad(format!("has scale {}", spec.scale)));
            }
            if !(spec.position.iter().all(|p| p.is_finite()) && spec.yaw_deg.is_finite()) {
                return Err(bad("has a non-finite pose".into()));
            }
            let mut object = PlacedObject {
                instance_id: index as u16 + 1,
                class_id: class.id,
                position: DVec3::new(spec.position[0], spec.position[1], 0.0),
                yaw: spec.yaw_deg.to_radians(),
                scale: spec.scale,
                color: spec.color.unwrap_or(class.color),
                parts: class.parts,
                support: None,
            };
            if let Some(on) = spec.on {
                let support = objects
                    .get(on)
                    .ok_or_else(|| bad(format!("stands on object {on}, not an earlier one")))?;
                let support_class = library::classes()
                    .into_iter()
                    .find(|c| c.id == support.class_id)
                    .ok_or_else(|| bad("support of an unknown class".into()))?;
                let surface = support_class.surfaces.get(spec.surface).ok_or_else(|| {
                    bad(format!(
                        "stands on surface {} of a {} that has {}",
                        spec.surface,
                        support_class.name,
                        support_class.surfaces.len()
                    ))
                })?;
                object.position.z = support.position.z + surface.z * support.scale;
                object.support = Some(support.instance_id);
                let (lo, hi) = object.bounds();
                if hi.z - lo.z > surface.clearance * support.scale + CONTACT {
                    return Err(bad(format!(
                        "is {:.2} m tall, the surface has {:.2} m of room",
                        hi.z - lo.z,
                        surface.clearance * support.scale
                    )));
                }
                // Every corner of the object's footprint lies on the surface's rectangle.
                let to_support = DQuat::from_rotation_z(-support.yaw);
                for corner in [
                    DVec3::new(lo.x, lo.y, 0.0),
                    DVec3::new(lo.x, hi.y, 0.0),
                    DVec3::new(hi.x, lo.y, 0.0),
                    DVec3::new(hi.x, hi.y, 0.0),
                ] {
                    let mut local = to_support * (corner - support.position) / support.scale;
                    local.x -= surface.center[0];
                    local.y -= surface.center[1];
                    if local.x.abs() > surface.half[0] + CONTACT
                        || local.y.abs() > surface.half[1] + CONTACT
                    {
                        return Err(bad(format!(
                            "overhangs the surface of object {on} (`{}`)",
                            support_class.name
                        )));
                    }
                }
            }
            let (lo, hi) = object.bounds();
            if lo.x < 0.0 || lo.y < 0.0 || hi.x > size.x || hi.y > size.y || hi.z > size.z {
                return Err(bad("does not fit in the room".into()));
            }
            for (other, (olo, ohi)) in bounds.iter().enumerate() {
                if Some(other) == spec.on {
                    continue;
                }
                let apart = (0..3).any(|a| lo[a] >= ohi[a] - CONTACT || olo[a] >= hi[a] - CONTACT);
                if !apart {
                    return Err(SceneError::Overlap(other, index));
                }
            }
            bounds.push((lo, hi));
            objects.push(object);
        }
        Ok(Scene {
            room_size: size,
            floor_color: self.room.floor_color,
            wall_color: self.room.wall_color,
            objects,
        })
    }

    /// The robot's pose at every frame of the trajectory.
    pub fn robot_poses(&self) -> Result<Vec<RobotPose>> {
        match &self.trajectory {
            Trajectory::Orbit {
                center,
                radius,
                frames,
                rate_hz,
            } => Ok((0..*frames)
                .map(|i| {
                    let angle = i as f64 / *frames as f64 * std::f64::consts::TAU;
                    let position = DVec3::new(
                        center[0] + radius * angle.cos(),
                        center[1] + radius * angle.sin(),
                        0.0,
                    );
                    RobotPose {
                        time_secs: i as f64 / rate_hz,
                        position,
                        // Facing the centre.
                        yaw: angle + std::f64::consts::PI,
                    }
                })
                .collect()),
            Trajectory::Waypoints {
                points,
                frames_per_segment,
                rate_hz,
            } => {
                if points.len() < 2 || *frames_per_segment == 0 {
                    return Err(SceneError::Invalid(
                        "waypoints need two points and frames per segment".into(),
                    ));
                }
                let mut poses = Vec::new();
                for pair in points.windows(2) {
                    for k in 0..*frames_per_segment {
                        let s = k as f64 / *frames_per_segment as f64;
                        let lerp = |a: f64, b: f64| a + (b - a) * s;
                        poses.push(RobotPose {
                            time_secs: poses.len() as f64 / rate_hz,
                            position: DVec3::new(
                                lerp(pair[0][0], pair[1][0]),
                                lerp(pair[0][1], pair[1][1]),
                                0.0,
                            ),
                            yaw: lerp(pair[0][2], pair[1][2]).to_radians(),
                        });
                    }
                }
                Ok(poses)
            }
            Trajectory::RandomWalk {
                start,
                frames,
                rate_hz,
                speed,
                turn_deg,
            } => {
                let scene = self.build()?;
                let mut position = DVec3::new(start[0], start[1], 0.0);
                if !is_free(&scene, position) {
                    return Err(SceneError::Invalid(format!(
                        "the random walk starts at {start:?}, inside an object or a wall"
                    )));
                }
                let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x7261_6e64_6f6d_5f77);
                let normal = rand_distr::Normal::new(0.0, turn_deg.to_radians().max(0.0))
                    .map_err(|e| SceneError::Invalid(e.to_string()))?;
                let step = speed / rate_hz;
                let mut yaw = start[2].to_radians();
                let mut poses = Vec::with_capacity(*frames);
                for i in 0..*frames {
                    poses.push(RobotPose {
                        time_secs: i as f64 / rate_hz,
                        position,
                        yaw,
                    });
                    yaw += rng.sample(normal);
                    // Blocked ahead: turn (a random way, by a growing angle) until free.
                    for attempt in 0..24 {
                        let next = position + step * DVec3::new(yaw.cos(), yaw.sin(), 0.0);
                        if is_free(&scene, next) {
                            position = next;
                            break;
                        }
                        let side = if rng.random::<bool>() { 1.0 } else { -1.0 };
                        yaw += side * (0.3 + 0.1 * f64::from(attempt));
                    }
                }
                Ok(poses)
            }
        }
    }
}

/// Whether the robot can stand at `position`: clear of walls and floor-standing objects.
pub fn is_free(scene: &Scene, position: DVec3) -> bool {
    let c = ROBOT_CLEARANCE;
    if position.x < c
        || position.y < c
        || position.x > scene.room_size.x - c
        || position.y > scene.room_size.y - c
    {
        return false;
    }
    scene.objects.iter().all(|object| {
        let (lo, hi) = object.bounds();
        position.x < lo.x - c
            || position.x > hi.x + c
            || position.y < lo.y - c
            || position.y > hi.y + c
    })
}

/// `world_from_camera` (REP-103 optical frame) of a camera mounted on a robot at `pose`.
pub fn camera_pose(camera: &CameraSpec, pose: &RobotPose) -> (DQuat, DVec3) {
    let world_from_base = DQuat::from_rotation_z(pose.yaw);
    let [x, y, z, w] = crate::testcard::BASE_FROM_OPTICAL;
    let base_from_optical = DQuat::from_xyzw(x, y, z, w);
    let tilt = DQuat::from_rotation_y(camera.pitch_deg.to_radians());
    let rotation = world_from_base * tilt * base_from_optical;
    let position = pose.position + world_from_base * DVec3::from(camera.mount);
    (rotation, position)
}

/// `base_from_optical` of a camera mount (for `/tf_static`).
pub fn mount_pose(camera: &CameraSpec) -> (DQuat, DVec3) {
    let [x, y, z, w] = crate::testcard::BASE_FROM_OPTICAL;
    let tilt = DQuat::from_rotation_y(camera.pitch_deg.to_radians());
    (
        tilt * DQuat::from_xyzw(x, y, z, w),
        DVec3::from(camera.mount),
    )
}

/// The pinhole model of a camera spec.
pub fn pinhole(camera: &CameraSpec) -> Pinhole {
    Pinhole::from_fov(camera.width, camera.height, camera.fov_x_deg.to_radians())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scenes_dir() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")
    }

    #[test]
    fn builtin_scenes_are_the_example_files() {
        for (name, _) in BUILTIN {
            let builtin = SceneFile::builtin(name).unwrap();
            let file = SceneFile::load(&scenes_dir().join(format!("{name}.toml"))).unwrap();
            assert_eq!(builtin, file);
        }
    }

    #[test]
    fn every_example_scene_parses_builds_and_renders() {
        let mut count = 0;
        for entry in std::fs::read_dir(scenes_dir()).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            let file = SceneFile::load(&path).unwrap_or_else(|e| panic!("{e}"));
            let scene = file
                .build()
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            let poses = file.robot_poses().unwrap();
            assert!(!poses.is_empty());
            let camera = &file.cameras[0];
            let (rotation, position) = camera_pose(camera, &poses[0]);
            let small = Pinhole::from_fov(64, 48, camera.fov_x_deg.to_radians());
            let view = crate::render::render(&scene, &small, rotation, position);
            assert!(
                view.instance.iter().any(|i| *i != 0),
                "{}: first frame sees an object",
                path.display()
            );
            count += 1;
        }
        assert!(count >= 1);
    }

    #[test]
    fn unknown_keys_classes_and_overlaps_are_errors() {
        let base = std::fs::read_to_string(scenes_dir().join("two_chairs.toml")).unwrap();
        let misspelt = format!("{base}\n[[effects]]\nkind = \"sensor_noise\"\nsigmaa = 2.0\n");
        assert!(
            toml::from_str::<SceneFile>(&misspelt).is_err(),
            "unknown effect key"
        );
        let unknown_effect = format!("{base}\n[[effects]]\nkind = \"lens_flare\"\n");
        assert!(toml::from_str::<SceneFile>(&unknown_effect).is_err());
        let unknown = base.replace("class = \"table\"", "class = \"spaceship\"");
        let file: SceneFile = toml::from_str(&unknown).unwrap();
        assert!(matches!(file.build(), Err(SceneError::UnknownClass(_))));
        let overlap = base.replace("position = [2.0, 2.6]", "position = [3.0, 2.5]");
        let file: SceneFile = toml::from_str(&overlap).unwrap();
        assert!(
            matches!(file.build(), Err(SceneError::Overlap(_, _))),
            "{:?}",
            file.build().err()
        );
        let outside = base.replace("position = [4.2, 3.4]", "position = [9.0, 3.4]");
        let file: SceneFile = toml::from_str(&outside).unwrap();
        assert!(matches!(file.build(), Err(SceneError::BadObject { .. })));
    }

    #[test]
    fn mounted_camera_looks_forward_along_the_robot_heading() {
        let camera = CameraSpec {
            name: "front".into(),
            width: 64,
            height: 48,
            fov_x_deg: 90.0,
            mount: [0.1, 0.0, 1.2],
            pitch_deg: 0.0,
        };
        let pose = RobotPose {
            time_secs: 0.0,
            position: DVec3::new(1.0, 2.0, 0.0),
            yaw: std::f64::consts::FRAC_PI_2,
        };
        let (rotation, position) = camera_pose(&camera, &pose);
        assert!(
            (rotation * DVec3::Z - DVec3::Y).length() < 1e-12,
            "optical z along the heading (+y)"
        );
        assert!(
            (rotation * DVec3::Y - DVec3::NEG_Z).length() < 1e-12,
            "optical y down"
        );
        assert!((position - DVec3::new(1.0, 2.1, 1.2)).length() < 1e-12);
    }
}
