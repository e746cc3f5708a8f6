//! Scene files (TOML): a room, objects from the library, a camera rig on the robot, and a
//! trajectory. Unknown keys are errors, so a misspelt key never silently becomes a default.
//! (Effects are not accepted yet: a scene that lists them is rejected rather than rendered without.)

use std::path::Path;

use glam::{DQuat, DVec3};
use serde::Deserialize;

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

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub name: String,
    pub room: RoomSpec,
    pub objects: Vec<ObjectSpec>,
    pub cameras: Vec<CameraSpec>,
    pub trajectory: Trajectory,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoomSpec {
    /// Extent along x, y, z (metres); the room spans [0, size].
    pub size: [f64; 3],
    pub floor_color: [f32; 3],
    pub wall_color: [f32; 3],
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSpec {
    pub class: String,
    /// Position of the object's base on the floor (x, y), metres.
    pub position: [f64; 2],
    #[serde(default)]
    pub yaw_deg: f64,
    #[serde(default = "unit")]
    pub scale: f64,
    /// Overrides the class colour.
    pub color: Option<[f32; 3]>,
}

fn unit() -> f64 {
    1.0
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
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

#[derive(Debug, Clone, PartialEq, Deserialize)]
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
}

/// The robot's pose at one frame: `world_from_base` and the stamp offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotPose {
    pub time_secs: f64,
    pub position: DVec3,
    pub yaw: f64,
}

impl SceneFile {
    pub fn load(path: &Path) -> Result<Self> {
        let read = |reason: String| SceneError::Read {
            path: path.display().to_string(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| read(e.to_string()))?;
        toml::from_str(&text).map_err(|e| read(e.to_string()))
    }

    /// Place the objects: library lookup, inside the room, no two objects' footprints overlapping.
    pub fn build(&self) -> Result<Scene> {
        let size = DVec3::from(self.room.size);
        if !(size.min_element() > 0.5 && size.is_finite()) {
            return Err(SceneError::Invalid(format!(
                "room size {:?} is not a room",
                self.room.size
            )));
        }
        let mut objects = Vec::new();
        let mut footprints = Vec::new();
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
            let object = PlacedObject {
                instance_id: index as u16 + 1,
                class_id: class.id,
                position: DVec3::new(spec.position[0], spec.position[1], 0.0),
                yaw: spec.yaw_deg.to_radians(),
                scale: spec.scale,
                color: spec.color.unwrap_or(class.color),
                parts: class.parts,
            };
            let (lo, hi) = footprint(&object);
            if lo.x < 0.0 || lo.y < 0.0 || hi.x > size.x || hi.y > size.y || hi.z > size.z {
                return Err(bad("does not fit in the room".into()));
            }
            for (other, (olo, ohi)) in footprints.iter().enumerate() {
                let (olo, ohi): (&DVec3, &DVec3) = (olo, ohi);
                if lo.x < ohi.x && olo.x < hi.x && lo.y < ohi.y && olo.y < hi.y {
                    return Err(SceneError::Overlap(other, index));
                }
            }
            footprints.push((lo, hi));
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
        }
    }
}

/// World-aligned bounds of an object (for placement checks).
fn footprint(object: &PlacedObject) -> (DVec3, DVec3) {
    let rotation = DQuat::from_rotation_z(object.yaw);
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for part in &object.parts {
        let (center, half) = match *part {
            library::Primitive::Box { center, half } => (DVec3::from(center), DVec3::from(half)),
            library::Primitive::Cylinder {
                center,
                radius,
                half_height,
            } => (DVec3::from(center), DVec3::new(radius, radius, half_height)),
        };
        for corner in 0..8 {
            let sign = DVec3::new(
                if corner & 1 == 0 { -1.0 } else { 1.0 },
                if corner & 2 == 0 { -1.0 } else { 1.0 },
                if corner & 4 == 0 { -1.0 } else { 1.0 },
            );
            let p = object.position + rotation * ((center + sign * half) * object.scale);
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    (lo, hi)
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
        let with_effects = format!("{base}\n[[effects]]\nkind = \"sensor_noise\"\n");
        assert!(
            toml::from_str::<SceneFile>(&with_effects).is_err(),
            "effects are not accepted yet"
        );
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
