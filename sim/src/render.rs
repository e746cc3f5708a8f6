//! CPU ray casting of analytic scenes with exact ground truth: RGB (Lambertian + ambient, with floor
//! tiles and value-noise texture on objects and walls), metric depth along the optical axis,
//! instance ids and class ids. Cameras use the REP-103 optical frame (z forward, x right, y down);
//! poses are `world_from_camera`.

use glam::{DQuat, DVec3};
use rayon::prelude::*;

use crate::library::Primitive;

/// An object placed in the world: the library class's parts, scaled, rotated about z and moved.
#[derive(Debug, Clone, PartialEq)]
pub struct PlacedObject {
    /// 1-based, unique in the scene; 0 is the room.
    pub instance_id: u16,
    pub class_id: u16,
    pub position: DVec3,
    pub yaw: f64,
    pub scale: f64,
    pub color: [f32; 3],
    pub parts: Vec<Primitive>,
    /// Instance id of the object this one stands on (`None`: the floor).
    pub support: Option<u16>,
}

impl PlacedObject {
    fn to_local(&self, p: DVec3) -> DVec3 {
        DQuat::from_rotation_z(-self.yaw) * (p - self.position) / self.scale
    }

    /// World-aligned bounding box (min, max corners) of the placed object.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let rotation = DQuat::from_rotation_z(self.yaw);
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for part in &self.parts {
            let (center, half) = part.extent();
            for corner in 0..8 {
                let sign = DVec3::new(
                    if corner & 1 == 0 { -1.0 } else { 1.0 },
                    if corner & 2 == 0 { -1.0 } else { 1.0 },
                    if corner & 4 == 0 { -1.0 } else { 1.0 },
                );
                let p = self.position + rotation * ((center + sign * half) * self.scale);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        (lo, hi)
    }

    /// The object's own box: the union of its parts in its frame, scaled, as its world centre and
    /// its size along its axes (turned by `yaw` about z). `None` for an object without parts.
    pub fn oriented_extent(&self) -> Option<(DVec3, DVec3)> {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for part in &self.parts {
            let (centre, half) = part.extent();
            lo = lo.min(centre - half);
            hi = hi.max(centre + half);
        }
        if !lo.is_finite() {
            return None;
        }
        let local_centre = (lo + hi) / 2.0 * self.scale;
        let (c, s) = (self.yaw.cos(), self.yaw.sin());
        let centre = self.position
            + DVec3::new(
                c * local_centre.x - s * local_centre.y,
                s * local_centre.x + c * local_centre.y,
                local_centre.z,
            );
        Some((centre, (hi - lo) * self.scale))
    }

    /// Signed distance (metres) from a world point to the object's surface.
    pub fn distance(&self, p: DVec3) -> f64 {
        let local = self.to_local(p);
        self.parts
            .iter()
            .map(|part| primitive_distance(part, local))
            .fold(f64::INFINITY, f64::min)
            * self.scale
    }
}

fn primitive_distance(part: &Primitive, p: DVec3) -> f64 {
    match *part {
        Primitive::Box { center, half } => {
            let q = (p - DVec3::from(center)).abs() - DVec3::from(half);
            q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
        }
        Primitive::Cylinder {
            center,
            radius,
            half_height,
        } => {
            let d = p - DVec3::from(center);
            let radial = (d.x * d.x + d.y * d.y).sqrt() - radius;
            let vertical = d.z.abs() - half_height;
            let outside = glam::DVec2::new(radial.max(0.0), vertical.max(0.0)).length();
            outside + radial.max(vertical).min(0.0)
        }
    }
}

/// A room spanning `[0, size]` on each axis, floor at z = 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub room_size: DVec3,
    pub floor_color: [f32; 3],
    pub wall_color: [f32; 3],
    pub objects: Vec<PlacedObject>,
}

/// A pinhole camera without distortion (distortion is an effect applied afterwards).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pinhole {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Pinhole {
    /// Square pixels, horizontal field of view `fov_x` (radians), centred principal point.
    pub fn from_fov(width: u32, height: u32, fov_x: f64) -> Self {
        let f = f64::from(width) / 2.0 / (fov_x / 2.0).tan();
        Self {
            width,
            height,
            fx: f,
            fy: f,
            cx: (f64::from(width) - 1.0) / 2.0,
            cy: (f64::from(height) - 1.0) / 2.0,
        }
    }
}

/// Plumb-bob (Brown-Conrady) lens distortion, as ROS `CameraInfo.d` = [k1, k2, p1, p2, k3] and
/// OpenCV define it, on normalised image coordinates. Deliberately independent of the node's
/// camera model: the simulator is the ground truth the node's undistortion is tested against.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlumbBob {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl PlumbBob {
    pub fn coefficients(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Ideal (undistorted) → distorted normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        (
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Distorted → ideal normalised coordinates: fixed-point iteration as OpenCV's
    /// `undistortPoints`, which converges for the moderate distortion of real lenses.
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..30 {
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            let dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
            let dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
            x = (xd - dx) / radial;
            y = (yd - dy) / radial;
        }
        (x, y)
    }
}

/// One rendered view with its ground truth, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedView {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
    /// Metres along the optical axis (z of the camera frame).
    pub depth: Vec<f32>,
    /// 0 for the room, else the object's instance id.
    pub instance: Vec<u16>,
    /// 0 for the room, else the library class id.
    pub class: Vec<u16>,
}

struct Hit {
    t: f64,
    normal: DVec3,
    object: Option<usize>,
}

/// Nearest intersection of a ray with a primitive (object frame), with its outward normal.
fn intersect(part: &Primitive, origin: DVec3, dir: DVec3) -> Option<(f64, DVec3)> {
    match *part {
        Primitive::Box { center, half } => {
            let (c, h) = (DVec3::from(center), DVec3::from(half));
            let (mut t_near, mut t_far) = (f64::NEG_INFINITY, f64::INFINITY);
            let mut axis = 0;
            for i in 0..3 {
                if dir[i].abs() < 1e-15 {
                    if (origin[i] - c[i]).abs() > h[i] {
                        return None;
                    }
                    continue;
                }
                let t1 = (c[i] - h[i] - origin[i]) / dir[i];
                let t2 = (c[i] + h[i] - origin[i]) / dir[i];
                let (lo, hi) = (t1.min(t2), t1.max(t2));
                if lo > t_near {
                    t_near = lo;
                    axis = i;
                }
                t_far = t_far.min(hi);
            }
            if t_near > t_far || t_near <= 1e-9 {
                return None;
            }
            let mut normal = DVec3::ZERO;
            normal[axis] = -dir[axis].signum();
            Some((t_near, normal))
        }
        Primitive::Cylinder {
            center,
            radius,
            half_height,
        } => {
            let c = DVec3::from(center);
            let o = origin - c;
            let mut best: Option<(f64, DVec3)> = None;
            let a = dir.x * dir.x + dir.y * dir.y;
            if a > 1e-15 {
                let b = o.x * dir.x + o.y * dir.y;
                let cc = o.x * o.x + o.y * o.y - radius * radius;
                let disc = b * b - a * cc;
                if disc >= 0.0 {
                    let t = (-b - disc.sqrt()) / a;
                    let z = o.z + t * dir.z;
                    if t > 1e-9 && z.abs() <= half_height {
                        let p = o + t * dir;
                        best = Some((t, DVec3::new(p.x, p.y, 0.0).normalize()));
                    }
                }
            }
            if dir.z.abs() > 1e-15 {
                for cap in [half_height, -half_height] {
                    let t = (cap - o.z) / dir.z;
                    let p = o + t * dir;
                    if t > 1e-9
                        && p.x * p.x + p.y * p.y <= radius * radius
                        && best.is_none_or(|(bt, _)| t < bt)
                    {
                        best = Some((t, DVec3::new(0.0, 0.0, cap.signum())));
                    }
                }
            }
            best
        }
    }
}

/// An object's rotations about z, to and from its own frame, and the box around its parts in that
/// frame, computed once per view: per ray and object the rotations were a third of a render's
/// time (`sincos`), and most rays pass most objects by, which the box tells at the cost of one
/// part.
#[derive(Clone, Copy)]
struct ObjectFrame {
    from_world: DQuat,
    to_world: DQuat,
    /// The parts' bounding box (object frame), padded so that rounding never hides a part.
    lo: DVec3,
    hi: DVec3,
}

/// Padding of an object's box (object frame, metres): far above the rounding of a slab test,
/// far below anything rendered.
const BOX_PADDING: f64 = 1e-6;

impl ObjectFrame {
    fn of(object: &PlacedObject) -> Self {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for part in &object.parts {
            let (centre, half) = part.extent();
            lo = lo.min(centre - half);
            hi = hi.max(centre + half);
        }
        Self {
            from_world: DQuat::from_rotation_z(-object.yaw),
            to_world: DQuat::from_rotation_z(object.yaw),
            lo: lo - BOX_PADDING,
            hi: hi + BOX_PADDING,
        }
    }

    /// Whether the ray (object frame) can meet a part before `nearest`: its entry into the
    /// padded box is at most `nearest` and its exit ahead of the origin. A miss here is a miss
    /// of every part, so skipping them changes no hit.
    fn may_hit_before(&self, origin: DVec3, dir: DVec3, nearest: f64) -> bool {
        let (mut enter, mut exit) = (f64::NEG_INFINITY, f64::INFINITY);
        for i in 0..3 {
            if dir[i] == 0.0 {
                if origin[i] < self.lo[i] || origin[i] > self.hi[i] {
                    return false;
                }
                continue;
            }
            let t1 = (self.lo[i] - origin[i]) / dir[i];
            let t2 = (self.hi[i] - origin[i]) / dir[i];
            enter = enter.max(t1.min(t2));
            exit = exit.min(t1.max(t2));
        }
        // An object without parts has an inverted box: whatever this says, it has nothing to hit.
        !(enter > exit || exit < 0.0 || enter > nearest)
    }

    fn local_point(&self, object: &PlacedObject, p: DVec3) -> DVec3 {
        self.from_world * (p - object.position) / object.scale
    }
}

fn cast(scene: &Scene, frames: &[ObjectFrame], origin: DVec3, dir: DVec3) -> Hit {
    // The room: where the ray leaves the box [0, size].
    let mut hit = Hit {
        t: f64::INFINITY,
        normal: DVec3::Z,
        object: None,
    };
    for i in 0..3 {
        if dir[i].abs() < 1e-15 {
            continue;
        }
        let bound = if dir[i] > 0.0 {
            scene.room_size[i]
        } else {
            0.0
        };
        let t = (bound - origin[i]) / dir[i];
        if t > 0.0 && t < hit.t {
            let mut normal = DVec3::ZERO;
            normal[i] = -dir[i].signum();
            hit = Hit {
                t,
                normal,
                object: None,
            };
        }
    }
    for (k, (object, frame)) in scene.objects.iter().zip(frames).enumerate() {
        let local_origin = frame.local_point(object, origin);
        let local_dir = frame.from_world * dir / object.scale;
        if !frame.may_hit_before(local_origin, local_dir, hit.t) {
            continue;
        }
        for part in &object.parts {
            if let Some((t, normal)) = intersect(part, local_origin, local_dir) {
                if t < hit.t {
                    hit = Hit {
                        t,
                        normal: frame.to_world * normal,
                        object: Some(k),
                    };
                }
            }
        }
    }
    hit
}

/// Value noise in [-1, 1], constant on cubes of `cell` metres: texture for photometric losses
/// and appearance features.
fn cell_noise(p: DVec3, cell: f64) -> f32 {
    let q = (p / cell).floor();
    let mut h = (q.x as i64 as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (q.y as i64 as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (q.z as i64 as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h = (h ^ (h >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h & 0xFFFF) as f32 / 32767.5 - 1.0
}

const LIGHT: DVec3 = DVec3::new(0.32, 0.48, 0.82);
const AMBIENT: f64 = 0.35;

/// Render one view of `scene`.
pub fn render(
    scene: &Scene,
    camera: &Pinhole,
    world_from_camera_rotation: DQuat,
    camera_position: DVec3,
) -> RenderedView {
    render_distorted(
        scene,
        camera,
        None,
        world_from_camera_rotation,
        camera_position,
    )
}

/// Render one view through a lens with `distortion`: each pixel casts the ray its distorted
/// coordinates come from, so images and ground truth are exactly what that lens sees.
pub fn render_distorted(
    scene: &Scene,
    camera: &Pinhole,
    distortion: Option<&PlumbBob>,
    world_from_camera_rotation: DQuat,
    camera_position: DVec3,
) -> RenderedView {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let forward = world_from_camera_rotation * DVec3::Z;
    let light = LIGHT.normalize();
    let frames: Vec<ObjectFrame> = scene.objects.iter().map(ObjectFrame::of).collect();
    let rows: Vec<RenderedView> = (0..h)
        .into_par_iter()
        .map(|v| {
            let mut row = RenderedView::with_capacity(camera.width, 1);
            for u in 0..w {
                let (x, y) = (
                    (u as f64 - camera.cx) / camera.fx,
                    (v as f64 - camera.cy) / camera.fy,
                );
                let (x, y) = match distortion {
                    Some(lens) => lens.undistort(x, y),
                    None => (x, y),
                };
                let ray_camera = DVec3::new(x, y, 1.0);
                let dir = world_from_camera_rotation * ray_camera;
                let hit = cast(scene, &frames, camera_position, dir);
                let point = camera_position + hit.t * dir;
                let (base, id, class_id) = match hit.object {
                    Some(k) => {
                        let o = &scene.objects[k];
                        // Texture fixed to the object (moves with it, equal on identical objects).
                        let shade = 1.0 + 0.08 * cell_noise(frames[k].local_point(o, point), 0.05);
                        (o.color.map(|c| c * shade), o.instance_id, o.class_id)
                    }
                    None if hit.normal.z > 0.5 => {
                        // Floor tiles of 0.5 m give texture for photometric losses.
                        let tile =
                            ((point.x / 0.5).floor() + (point.y / 0.5).floor()).rem_euclid(2.0);
                        let shade = if tile < 1.0 { 1.0 } else { 0.85 };
                        (scene.floor_color.map(|c| c * shade), 0, 0)
                    }
                    None => {
                        let shade = 1.0 + 0.03 * cell_noise(point, 0.2);
                        (scene.wall_color.map(|c| c * shade), 0, 0)
                    }
                };
                let lambert = AMBIENT + (1.0 - AMBIENT) * hit.normal.dot(light).max(0.0);
                for c in base {
                    row.rgb
                        .push((f64::from(c) * lambert * 255.0).round().clamp(0.0, 255.0) as u8);
                }
                row.depth
                    .push(((point - camera_position).dot(forward)) as f32);
                row.instance.push(id);
                row.class.push(class_id);
            }
            row
        })
        .collect();
    let mut out = RenderedView::with_capacity(camera.width, camera.height);
    for row in rows {
        out.rgb.extend(row.rgb);
        out.depth.extend(row.depth);
        out.instance.extend(row.instance);
        out.class.extend(row.class);
    }
    out
}

impl RenderedView {
    fn with_capacity(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            rgb: Vec::with_capacity(n * 3),
            depth: Vec::with_capacity(n),
            instance: Vec::with_capacity(n),
            class: Vec::with_capacity(n),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::library::class;

    fn scene() -> Scene {
        let place = |instance_id: u16, name: &str, x: f64, y: f64, yaw: f64| {
            let c = class(name).unwrap();
            PlacedObject {
                instance_id,
                class_id: c.id,
                position: DVec3::new(x, y, 0.0),
                yaw,
                scale: 1.0,
                color: c.color,
                parts: c.parts,
                support: None,
            }
        };
        Scene {
            room_size: DVec3::new(6.0, 5.0, 2.8),
            floor_color: [0.6, 0.55, 0.5],
            wall_color: [0.85, 0.85, 0.8],
            objects: vec![
                place(1, "table", 3.0, 2.5, 0.3),
                place(2, "chair", 2.2, 2.4, 1.2),
                place(3, "trash bin", 4.2, 3.2, 0.0),
                place(4, "chair", 3.6, 1.8, -0.4),
                place(5, "lamp", 1.2, 4.0, 0.0),
            ],
        }
    }

    /// A camera at 1.3 m looking horizontally along +x from the room's left side.
    fn pose() -> (DQuat, DVec3) {
        // Optical z → world +x, optical x → world -y, optical y → world -z (the body mounting).
        let [x, y, z, w] = crate::testcard::BASE_FROM_OPTICAL;
        let rotation = DQuat::from_xyzw(x, y, z, w);
        let pitch_down = DQuat::from_rotation_x(-0.35);
        (rotation * pitch_down, DVec3::new(0.4, 2.6, 1.3))
    }

    #[test]
    fn skipping_objects_whose_box_a_ray_misses_changes_no_hit() {
        // Every ray of a fan from three places (one inside the table's box, one level with the
        // chair seats, one grazing the floor) hits exactly what a cast through every part of
        // every object hits, to the bit; and most rays do skip most objects.
        let scene = scene();
        let frames: Vec<ObjectFrame> = scene.objects.iter().map(ObjectFrame::of).collect();
        let every_part: Vec<ObjectFrame> = frames
            .iter()
            .map(|f| ObjectFrame {
                lo: DVec3::splat(f64::NEG_INFINITY),
                hi: DVec3::splat(f64::INFINITY),
                ..*f
            })
            .collect();
        let (mut rays, mut skipped) = (0, 0);
        for origin in [
            DVec3::new(3.0, 2.5, 0.7),
            DVec3::new(0.3, 0.4, 0.45),
            DVec3::new(5.8, 4.7, 0.01),
        ] {
            for i in 0..60 {
                for j in 0..30 {
                    let (yaw, pitch) = (i as f64 * 0.1047, j as f64 * 0.1 - 1.5);
                    let dir = DVec3::new(
                        yaw.cos() * pitch.cos(),
                        yaw.sin() * pitch.cos(),
                        pitch.sin(),
                    );
                    let (pruned, brute) = (
                        cast(&scene, &frames, origin, dir),
                        cast(&scene, &every_part, origin, dir),
                    );
                    assert_eq!(pruned.t.to_bits(), brute.t.to_bits(), "{origin} {dir}");
                    assert_eq!((pruned.object, pruned.normal), (brute.object, brute.normal));
                    rays += 1;
                    skipped += scene
                        .objects
                        .iter()
                        .zip(&frames)
                        .filter(|(o, f)| {
                            !f.may_hit_before(
                                f.local_point(o, origin),
                                f.from_world * dir / o.scale,
                                f64::INFINITY,
                            )
                        })
                        .count();
                }
            }
        }
        assert!(
            skipped > rays * scene.objects.len() / 2,
            "{skipped} of {rays} rays"
        );
    }

    #[test]
    fn rendering_is_deterministic_and_sees_every_placed_object() {
        let camera = Pinhole::from_fov(160, 120, 1.6);
        let (rotation, position) = pose();
        let a = render(&scene(), &camera, rotation, position);
        assert_eq!(a, render(&scene(), &camera, rotation, position));
        for id in 1..=4u16 {
            assert!(
                a.instance.iter().filter(|i| **i == id).count() > 20,
                "instance {id} visible"
            );
        }
        assert!(a.depth.iter().all(|d| d.is_finite() && *d > 0.0));
        // Two chairs: distinct instances, one class.
        let chair = class("chair").unwrap().id;
        let chair_instances: std::collections::BTreeSet<u16> = a
            .instance
            .iter()
            .zip(&a.class)
            .filter(|(_, c)| **c == chair)
            .map(|(i, _)| *i)
            .collect();
        assert_eq!(chair_instances.into_iter().collect::<Vec<_>>(), vec![2, 4]);
    }

    #[test]
    fn ground_truth_reprojects_onto_the_object_surface_within_a_millimetre() {
        let camera = Pinhole::from_fov(128, 96, 1.6);
        let (rotation, position) = pose();
        let scene = scene();
        let view = render(&scene, &camera, rotation, position);
        let mut checked = 0;
        for v in 0..96 {
            for u in 0..128 {
                let i = v * 128 + u;
                let id = view.instance[i];
                let z = f64::from(view.depth[i]);
                let ray = DVec3::new(
                    (u as f64 - camera.cx) / camera.fx,
                    (v as f64 - camera.cy) / camera.fy,
                    1.0,
                );
                let world = position + rotation * (ray * z);
                if id == 0 {
                    // Room pixels lie on a wall, the floor or the ceiling.
                    let s = scene.room_size;
                    let off = [
                        world.x,
                        s.x - world.x,
                        world.y,
                        s.y - world.y,
                        world.z,
                        s.z - world.z,
                    ]
                    .into_iter()
                    .map(f64::abs)
                    .fold(f64::INFINITY, f64::min);
                    assert!(off < 1e-3, "room pixel ({u},{v}) is {off} m off its wall");
                    continue;
                }
                let object = scene.objects.iter().find(|o| o.instance_id == id).unwrap();
                let distance = object.distance(world).abs();
                assert!(
                    distance < 1e-3,
                    "pixel ({u},{v}) of instance {id} is {distance} m off its surface"
                );
                checked += 1;
            }
        }
        assert!(checked > 300, "only {checked} object pixels");
    }
}
