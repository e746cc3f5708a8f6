//! A scene file played over time: the robot's trajectory, the cameras' views with ground truth,
//! and the effects the scene lists (and only those).

use glam::{DQuat, DVec3};
use rand::seq::SliceRandom;
use rand::Rng;
use rand_distr::{Distribution, Normal};

use crate::effects::{self, Effect, Stream};
use crate::render::{render_distorted, Pinhole, PlumbBob, RenderedView, Scene};
use crate::scene::{camera_pose, pinhole, RobotPose, SceneError, SceneFile};

/// One object sliding back and forth (the `moving_objects` effect).
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    /// Index into the scene's objects; objects standing on it move with it.
    pub object: usize,
    pub direction: DVec3,
    pub amplitude: f64,
    pub period_secs: f64,
    pub phase: f64,
}

/// A scene ready to be played: built, with its trajectory and effect state.
#[derive(Debug, Clone)]
pub struct Simulation {
    pub file: SceneFile,
    /// The scene at time 0 (moving objects at their rest position).
    pub scene: Scene,
    pub poses: Vec<RobotPose>,
    pub motions: Vec<Motion>,
    /// Odometry error (translation, yaw) per frame; empty without `odometry_drift`.
    drift: Vec<(DVec3, f64)>,
}

/// One camera's view at one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SimView {
    pub camera: usize,
    pub pinhole: Pinhole,
    pub distortion: Option<PlumbBob>,
    /// `world_from_camera` (REP-103 optical frame), true.
    pub rotation: DQuat,
    pub position: DVec3,
    /// Exact ground truth: clean RGB, exact depth, instance and class ids.
    pub truth: RenderedView,
    /// What the sensor recorded, where an effect changed it; `None` means the clean render.
    pub rgb: Option<Vec<u8>>,
    pub depth: Option<Vec<f32>>,
}

impl SimView {
    pub fn sensor_rgb(&self) -> &[u8] {
        self.rgb.as_deref().unwrap_or(&self.truth.rgb)
    }

    pub fn sensor_depth(&self) -> &[f32] {
        self.depth.as_deref().unwrap_or(&self.truth.depth)
    }
}

/// Everything at one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SimFrame {
    pub index: usize,
    /// True capture time, seconds from the start.
    pub time_secs: f64,
    /// The stamp the camera writes into its headers (capture time plus jitter).
    pub stamp_secs: f64,
    /// The camera messages of this frame were lost (`views` is empty).
    pub dropped: bool,
    pub robot: RobotPose,
    /// The pose odometry reports on `/tf` (the true pose plus drift).
    pub odometry: RobotPose,
    /// The scene at this instant (objects where they are now).
    pub scene: Scene,
    pub views: Vec<SimView>,
}

impl Simulation {
    pub fn new(mut file: SceneFile) -> Result<Self, SceneError> {
        file.effects = file.resolved_effects()?;
        file.effects_preset = None;
        let scene = file.build()?;
        let poses = file.robot_poses()?;
        if poses.is_empty() {
            return Err(SceneError::Invalid("the trajectory has no frames".into()));
        }
        let mut seen = std::collections::BTreeSet::new();
        for effect in &file.effects {
            if !seen.insert(effect.kind()) {
                return Err(SceneError::Invalid(format!(
                    "effect {} is listed twice",
                    effect.kind()
                )));
            }
        }
        let mut simulation = Self {
            file,
            scene,
            poses,
            motions: Vec::new(),
            drift: Vec::new(),
        };
        for effect in simulation.file.effects.clone() {
            match effect {
                Effect::MovingObjects {
                    count,
                    amplitude_m,
                    period_secs,
                } => simulation.motions = simulation.plan_motions(count, amplitude_m, period_secs),
                Effect::OdometryDrift {
                    sigma_m,
                    sigma_yaw_deg,
                } => simulation.drift = simulation.plan_drift(sigma_m, sigma_yaw_deg),
                _ => {}
            }
        }
        Ok(simulation)
    }

    pub fn frame_count(&self) -> usize {
        self.poses.len()
    }

    pub fn rate_hz(&self) -> f64 {
        if self.poses.len() < 2 {
            return 10.0;
        }
        1.0 / (self.poses[1].time_secs - self.poses[0].time_secs)
    }

    fn effect(&self, kind: &str) -> Option<&Effect> {
        self.file.effects.iter().find(|e| e.kind() == kind)
    }

    /// Pick objects on the floor that carry nothing, and a direction each can slide along without
    /// touching anything over its whole swing.
    fn plan_motions(&self, count: usize, amplitude: f64, period_secs: f64) -> Vec<Motion> {
        let mut rng = effects::rng(self.file.seed, Stream::MovingObjects, 0, 0);
        let objects = &self.scene.objects;
        let mut candidates: Vec<usize> = (0..objects.len())
            .filter(|&k| {
                objects[k].support.is_none()
                    && !objects
                        .iter()
                        .any(|o| o.support == Some(objects[k].instance_id))
            })
            .collect();
        candidates.shuffle(&mut rng);
        let mut motions: Vec<Motion> = Vec::new();
        for k in candidates {
            if motions.len() == count {
                break;
            }
            for _ in 0..8 {
                let angle = rng.random::<f64>() * std::f64::consts::TAU;
                let direction = DVec3::new(angle.cos(), angle.sin(), 0.0);
                let (lo, hi) = objects[k].bounds();
                let sweep = direction.abs() * amplitude;
                let (lo, hi) = (lo - sweep, hi + sweep);
                let inside = lo.x > 0.0
                    && lo.y > 0.0
                    && hi.x < self.scene.room_size.x
                    && hi.y < self.scene.room_size.y;
                // Clear of every other object, including the other movers' swings.
                let clear = objects.iter().enumerate().all(|(j, other)| {
                    if j == k {
                        return true;
                    }
                    let (mut olo, mut ohi) = other.bounds();
                    if let Some(m) = motions.iter().find(|m| m.object == j) {
                        let s = m.direction.abs() * m.amplitude;
                        olo -= s;
                        ohi += s;
                    }
                    (0..3).any(|a| lo[a] >= ohi[a] || olo[a] >= hi[a])
                });
                if inside && clear {
                    motions.push(Motion {
                        object: k,
                        direction,
                        amplitude,
                        period_secs,
                        phase: rng.random::<f64>() * std::f64::consts::TAU,
                    });
                    break;
                }
            }
        }
        motions
    }

    fn plan_drift(&self, sigma_m: f64, sigma_yaw_deg: f64) -> Vec<(DVec3, f64)> {
        let mut drift = Vec::with_capacity(self.poses.len());
        let (mut offset, mut yaw) = (DVec3::ZERO, 0.0);
        let mut previous = self.poses[0].time_secs;
        for (i, pose) in self.poses.iter().enumerate() {
            let dt = (pose.time_secs - previous).max(0.0);
            previous = pose.time_secs;
            let mut rng = effects::rng(self.file.seed, Stream::OdometryDrift, i as u64, 0);
            if let (Ok(step), Ok(turn)) = (
                Normal::new(0.0, sigma_m * dt.sqrt()),
                Normal::new(0.0, sigma_yaw_deg.to_radians() * dt.sqrt()),
            ) {
                offset += DVec3::new(step.sample(&mut rng), step.sample(&mut rng), 0.0);
                yaw += turn.sample(&mut rng);
            }
            drift.push((offset, yaw));
        }
        drift
    }

    /// The scene at `time_secs`: moving objects (and what stands on them) displaced.
    pub fn scene_at(&self, time_secs: f64) -> Scene {
        let mut scene = self.scene.clone();
        for motion in &self.motions {
            let offset = motion.direction
                * motion.amplitude
                * (time_secs / motion.period_secs * std::f64::consts::TAU + motion.phase).sin();
            let id = scene.objects[motion.object].instance_id;
            for object in &mut scene.objects {
                if object.instance_id == id || object.support == Some(id) {
                    object.position += offset;
                }
            }
        }
        scene
    }

    /// The robot's pose at any time, interpolated between frames (clamped at the ends).
    pub fn robot_at(&self, time_secs: f64) -> RobotPose {
        let poses = &self.poses;
        let after = poses.partition_point(|p| p.time_secs <= time_secs);
        if after == 0 {
            return poses[0];
        }
        if after == poses.len() {
            return poses[poses.len() - 1];
        }
        let (a, b) = (poses[after - 1], poses[after]);
        let s = (time_secs - a.time_secs) / (b.time_secs - a.time_secs).max(1e-12);
        let turn = (b.yaw - a.yaw + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        RobotPose {
            time_secs,
            position: a.position.lerp(b.position, s),
            yaw: a.yaw + s * turn,
        }
    }

    /// Render frame `index` with the scene's effects.
    pub fn frame(&self, index: usize) -> SimFrame {
        let robot = self.poses[index.min(self.poses.len() - 1)];
        let time = robot.time_secs;
        let frame = index as u64;
        let seed = self.file.seed;
        let dropped = match self.effect("frame_drops") {
            Some(Effect::FrameDrops { probability }) => {
                effects::rng(seed, Stream::FrameDrops, frame, 0).random::<f64>() < *probability
            }
            _ => false,
        };
        let stamp_secs = match self.effect("timestamp_jitter") {
            Some(Effect::TimestampJitter { sigma_secs }) => {
                let mut rng = effects::rng(seed, Stream::TimestampJitter, frame, 0);
                time + Normal::new(0.0, *sigma_secs).map_or(0.0, |n| n.sample(&mut rng))
            }
            _ => time,
        };
        let odometry = match self.drift.get(index) {
            Some((offset, yaw)) => RobotPose {
                position: robot.position + *offset,
                yaw: robot.yaw + yaw,
                ..robot
            },
            None => robot,
        };
        let scene = self.scene_at(time);
        let views = if dropped {
            Vec::new()
        } else {
            (0..self.file.cameras.len())
                .map(|camera| self.view(&scene, camera, &robot, frame))
                .collect()
        };
        SimFrame {
            index,
            time_secs: time,
            stamp_secs,
            dropped,
            robot,
            odometry,
            scene,
            views,
        }
    }

    fn view(&self, scene: &Scene, camera: usize, robot: &RobotPose, frame: u64) -> SimView {
        let spec = &self.file.cameras[camera];
        let pinhole = pinhole(spec);
        let distortion = self.file.effects.iter().find_map(Effect::lens);
        let (rotation, position) = camera_pose(spec, robot);
        let truth = render_distorted(scene, &pinhole, distortion.as_ref(), rotation, position);
        let mut view = SimView {
            camera,
            pinhole,
            distortion,
            rotation,
            position,
            truth,
            rgb: None,
            depth: None,
        };
        let seed = self.file.seed;
        // The physical order: shutter, exposure, read noise.
        if let Some(Effect::MotionBlur {
            exposure_secs,
            samples,
        }) = self.effect("motion_blur")
        {
            let mut sum = vec![0.0f32; view.truth.rgb.len()];
            for s in 0..*samples {
                let t = robot.time_secs - exposure_secs * s as f64 / (*samples - 1) as f64;
                let (r, p) = camera_pose(spec, &self.robot_at(t));
                let shot = render_distorted(&self.scene_at(t), &pinhole, distortion.as_ref(), r, p);
                for (acc, value) in sum.iter_mut().zip(&shot.rgb) {
                    *acc += f32::from(*value);
                }
            }
            let n = *samples as f32;
            view.rgb = Some(sum.iter().map(|v| (v / n).round() as u8).collect());
        }
        if let Some(Effect::Exposure {
            min_gain,
            max_gain,
            period_secs,
        }) = self.effect("exposure")
        {
            let gain = effects::exposure_gain(*min_gain, *max_gain, *period_secs, robot.time_secs);
            let rgb = view.rgb.get_or_insert_with(|| view.truth.rgb.clone());
            effects::apply_gain(rgb, gain);
        }
        if let Some(Effect::SensorNoise { sigma }) = self.effect("sensor_noise") {
            let mut rng = effects::rng(seed, Stream::SensorNoise, frame, camera as u64);
            let rgb = view.rgb.get_or_insert_with(|| view.truth.rgb.clone());
            effects::add_sensor_noise(rgb, *sigma, &mut rng);
        }
        if let Some(Effect::DepthNoise { sigma_at_1m }) = self.effect("depth_noise") {
            let mut rng = effects::rng(seed, Stream::DepthNoise, frame, camera as u64);
            let depth = view.depth.get_or_insert_with(|| view.truth.depth.clone());
            effects::add_depth_noise(depth, *sigma_at_1m, &mut rng);
        }
        if let Some(Effect::DepthDropout {
            probability,
            edge_m,
        }) = self.effect("depth_dropout")
        {
            let mut rng = effects::rng(seed, Stream::DepthDropout, frame, camera as u64);
            let depth = view.depth.get_or_insert_with(|| view.truth.depth.clone());
            effects::drop_depth(
                depth,
                &view.truth.depth,
                view.truth.width as usize,
                *probability,
                *edge_m,
                &mut rng,
            );
        }
        view
    }
}
