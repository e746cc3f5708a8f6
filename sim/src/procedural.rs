//! Procedural scenes: seeded, physically plausible room layouts in named splits.
//!
//! Large furniture stands against a wall with its back to it, chairs gather around tables, small
//! objects stand on the surfaces that carry them (a lamp on a table, a monitor on a desk, a box on
//! a shelf, a pillow on a bed), and several instances of one class are common — often identical
//! in colour, the hard case for instance grouping. Every candidate placement is checked by
//! [`SceneFile::build`], so generated scenes obey the same support and no-overlap rules as
//! hand-written ones.

use rand::seq::IndexedRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::library::{self, Placement};
use crate::scene::{is_free, CameraSpec, ObjectSpec, RoomSpec, SceneFile, Trajectory};

/// Named scene sets on disjoint seed ranges: a model never trains on a scene it is validated or
/// benchmarked on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    Train,
    Val,
    Benchmark,
    /// Arrangements the other splits rarely hold: rows of identical objects side by side,
    /// chairs lined up at tables, several objects on one surface, objects in corners. A test
    /// split for the map's neighbours (its own seeds).
    Layouts,
    /// The `layouts` generator with seeds of its own, for training data: the model may learn
    /// what the `layouts` test split asks without seeing its rooms.
    LayoutsTrain,
}

impl Split {
    pub const ALL: [Split; 5] = [
        Split::Train,
        Split::Val,
        Split::Benchmark,
        Split::Layouts,
        Split::LayoutsTrain,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Benchmark => "benchmark",
            Split::Layouts => "layouts",
            Split::LayoutsTrain => "layouts_train",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }

    /// Scenes per split: indices at or beyond this are refused, so ranges never meet.
    pub const CAPACITY: u64 = 1 << 40;

    /// The seed of scene `index` of this split.
    pub fn seed(self, index: u64) -> Option<u64> {
        let base = match self {
            Split::Train => 0,
            Split::Val => 1,
            Split::Benchmark => 2,
            Split::Layouts => 3,
            Split::LayoutsTrain => 4,
        };
        (index < Self::CAPACITY).then(|| base * Self::CAPACITY + index)
    }
}

impl std::fmt::Display for Split {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Options of the generated rig and trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct ProceduralOptions {
    pub width: u32,
    pub height: u32,
    pub fov_x_deg: f64,
    pub frames: usize,
    pub rate_hz: f64,
}

impl Default for ProceduralOptions {
    fn default() -> Self {
        Self {
            width: 320,
            height: 240,
            fov_x_deg: 90.0,
            frames: 60,
            rate_hz: 10.0,
        }
    }
}

/// Classes that stand against a wall, with the local direction (±y) of their back.
fn wall_back(class: &str) -> Option<f64> {
    match class {
        "bed" | "bookshelf" | "toilet" => Some(1.0),
        "sofa" | "cabinet" | "refrigerator" | "desk" | "sink" => Some(-1.0),
        _ => None,
    }
}

/// Floor classes with their weight in a room.
const FLOOR_CLASSES: &[(&str, u32)] = &[
    ("chair", 3),
    ("table", 3),
    ("desk", 2),
    ("cabinet", 2),
    ("trash bin", 2),
    ("sink", 1),
    ("bed", 1),
    ("sofa", 1),
    ("bookshelf", 2),
    ("toilet", 1),
    ("refrigerator", 1),
    ("plant", 1),
    ("box", 1),
];

fn jitter_color(rng: &mut ChaCha8Rng, color: [f32; 3], amount: f32) -> [f32; 3] {
    color.map(|c| (c + rng.random_range(-amount..=amount)).clamp(0.02, 0.98))
}

/// Try adding `spec`; keep it only if the scene still builds.
fn try_add(file: &mut SceneFile, spec: ObjectSpec) -> bool {
    file.objects.push(spec);
    if file.build().is_ok() {
        true
    } else {
        file.objects.pop();
        false
    }
}

/// Scene `index` of `split`, with the default rig.
pub fn generate(split: Split, index: u64) -> Option<SceneFile> {
    generate_with(split, index, &ProceduralOptions::default())
}

/// Scene `index` of `split`; `None` if the index is outside the split's range.
pub fn generate_with(split: Split, index: u64, options: &ProceduralOptions) -> Option<SceneFile> {
    let seed = split.seed(index)?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let size = [
        rng.random_range(4.5..8.0),
        rng.random_range(4.0..7.0),
        rng.random_range(2.6..3.0),
    ];
    let floor = [[0.6, 0.55, 0.5], [0.45, 0.35, 0.25], [0.7, 0.7, 0.68]]
        .choose(&mut rng)
        .copied()
        .unwrap_or([0.6, 0.55, 0.5]);
    let mut file = SceneFile {
        name: format!("{split}_{index:05}"),
        seed,
        room: RoomSpec {
            size,
            floor_color: jitter_color(&mut rng, floor, 0.05),
            wall_color: jitter_color(&mut rng, [0.85, 0.85, 0.8], 0.05),
        },
        objects: Vec::new(),
        cameras: vec![CameraSpec {
            name: "camera".into(),
            width: options.width,
            height: options.height,
            fov_x_deg: options.fov_x_deg,
            mount: [0.1, 0.0, 1.2],
            pitch_deg: 20.0,
        }],
        trajectory: Trajectory::Orbit {
            center: [size[0] / 2.0, size[1] / 2.0],
            radius: 0.5,
            frames: 1,
            rate_hz: options.rate_hz,
        },
        effects: Vec::new(),
        effects_preset: None,
    };

    match split {
        Split::Layouts | Split::LayoutsTrain => place_rows(&mut file, &mut rng, size),
        _ => place_floor_objects(&mut file, &mut rng, size),
    }
    place_chairs_at_tables(&mut file, &mut rng);
    place_small_objects(&mut file, &mut rng);
    place_robot(file, &mut rng, size, options)
}

/// Where an object of `class` (scaled by `scale`) stands with its back (local ±y, `back`) to wall
/// `wall` (0: x = 0, 1: x = size, 2: y = 0, 3: y = size), `along` metres along it, 2 cm off it.
#[derive(Debug, Clone, Copy)]
struct WallPose {
    position: [f64; 2],
    yaw_deg: f64,
    /// Its extent along the wall.
    width: f64,
}

fn wall_pose(
    class: &library::ObjectClass,
    back: f64,
    wall: usize,
    along: f64,
    scale: f64,
    size: [f64; 3],
) -> WallPose {
    let normal: [f64; 2] = match wall {
        0 => [-1.0, 0.0],
        1 => [1.0, 0.0],
        2 => [0.0, -1.0],
        _ => [0.0, 1.0],
    };
    // Local (0, back) must point along the wall's outward normal.
    let yaw = normal[1].atan2(normal[0]) - back * std::f64::consts::FRAC_PI_2;
    let (lo, hi) = placed_bounds(class, yaw, scale);
    let gap = 0.02;
    let (position, width) = match wall {
        0 => ([-lo.x + gap, along], hi.y - lo.y),
        1 => ([size[0] - hi.x - gap, along], hi.y - lo.y),
        2 => ([along, -lo.y + gap], hi.x - lo.x),
        _ => ([along, size[1] - hi.y - gap], hi.x - lo.x),
    };
    WallPose {
        position,
        yaw_deg: yaw.to_degrees(),
        width,
    }
}

/// Floor objects: a mix of classes where repeats are common, against the walls or anywhere.
fn place_floor_objects(file: &mut SceneFile, rng: &mut ChaCha8Rng, size: [f64; 3]) {
    // Floor objects: a mix of classes where repeats are common.
    let wanted = rng.random_range(5..=10);
    let mut chosen: Vec<&str> = Vec::new();
    while chosen.len() < wanted {
        let repeat = !chosen.is_empty() && rng.random::<f64>() < 0.4;
        let class = if repeat {
            chosen.choose(rng).copied().unwrap_or("chair")
        } else {
            FLOOR_CLASSES
                .choose_weighted(rng, |(_, w)| *w)
                .map(|(c, _)| *c)
                .unwrap_or("chair")
        };
        chosen.push(class);
    }
    // Instances of one class share a colour half the time (identical-looking objects).
    let mut class_colors: std::collections::BTreeMap<&str, [f32; 3]> = Default::default();
    for class_name in chosen {
        let Some(class) = library::class(class_name) else {
            continue;
        };
        let color = match class_colors.get(class_name) {
            Some(c) if rng.random::<bool>() => *c,
            _ => {
                let c = jitter_color(rng, class.color, 0.12);
                class_colors.insert(class_name, c);
                c
            }
        };
        for _ in 0..40 {
            let scale = rng.random_range(library::SCALE_RANGE.0..library::SCALE_RANGE.1);
            let (position, yaw_deg) = match wall_back(class_name) {
                Some(back) => {
                    // Against one of the four walls, back to it.
                    let wall = rng.random_range(0..4);
                    let along = match wall {
                        0 | 1 => rng.random_range(0.0..size[1]),
                        _ => rng.random_range(0.0..size[0]),
                    };
                    let pose = wall_pose(&class, back, wall, along, scale, size);
                    (pose.position, pose.yaw_deg)
                }
                None => (
                    [
                        rng.random_range(0.4..size[0] - 0.4),
                        rng.random_range(0.4..size[1] - 0.4),
                    ],
                    rng.random_range(-180.0..180.0),
                ),
            };
            let spec = ObjectSpec {
                class: class_name.into(),
                position,
                yaw_deg,
                scale,
                color: Some(color),
                on: None,
                surface: 0,
            };
            if try_add(file, spec) {
                break;
            }
        }
    }
}

/// Classes that stand in rows along a wall (with their weight) and free-standing ones.
const WALL_ROW_CLASSES: &[(&str, u32)] = &[
    ("cabinet", 3),
    ("desk", 2),
    ("bookshelf", 2),
    ("refrigerator", 1),
];
const FREE_ROW_CLASSES: &[&str] = &["chair", "box", "trash bin"];

/// The `layouts` split's floor: one to three rows of 2 to 6 identical objects side by side along
/// walls (touching or a few centimetres apart; a row may start in a corner), a free-standing row
/// of 2 to 4 chairs, boxes or bins facing one way, and a table with chairs lined up along one
/// side.
fn place_rows(file: &mut SceneFile, rng: &mut ChaCha8Rng, size: [f64; 3]) {
    for _ in 0..rng.random_range(1..=3) {
        place_wall_row(file, rng, size);
    }
    place_free_row(file, rng, size);
    place_table_with_a_row_of_chairs(file, rng, size);
}

/// A row of identical objects with their backs to one wall.
fn place_wall_row(file: &mut SceneFile, rng: &mut ChaCha8Rng, size: [f64; 3]) {
    let Some(name) = WALL_ROW_CLASSES
        .choose_weighted(rng, |(_, w)| *w)
        .map(|(c, _)| *c)
        .ok()
    else {
        return;
    };
    let (Some(class), Some(back)) = (library::class(name), wall_back(name)) else {
        return;
    };
    let wall = rng.random_range(0..4);
    let length = if wall < 2 { size[1] } else { size[0] };
    let scale = rng.random_range(library::SCALE_RANGE.0..library::SCALE_RANGE.1);
    let color = jitter_color(rng, class.color, 0.12);
    let gap = [0.0, 0.01, 0.03, 0.05][rng.random_range(0..4)];
    let width = wall_pose(&class, back, wall, 0.0, scale, size).width;
    let fits = ((length - 0.1 + gap) / (width + gap)).floor().max(0.0) as usize;
    let count = rng.random_range(2..=6).min(fits);
    let span = count as f64 * width + count.saturating_sub(1) as f64 * gap;
    // Half the rows start in a corner, against two walls.
    let start = if rng.random::<bool>() {
        0.03
    } else {
        rng.random_range(0.03..(length - span - 0.03).max(0.04))
    };
    for k in 0..count {
        let along = start + width / 2.0 + k as f64 * (width + gap);
        let pose = wall_pose(&class, back, wall, along, scale, size);
        try_add(
            file,
            ObjectSpec {
                class: name.into(),
                position: pose.position,
                yaw_deg: pose.yaw_deg,
                scale,
                color: Some(color),
                on: None,
                surface: 0,
            },
        );
    }
}

/// The world bounds of an object of `class` placed at the origin, turned by `yaw`, scaled.
fn placed_bounds(class: &library::ObjectClass, yaw: f64, scale: f64) -> (glam::DVec3, glam::DVec3) {
    crate::render::PlacedObject {
        instance_id: 0,
        class_id: class.id,
        position: glam::DVec3::ZERO,
        yaw,
        scale,
        color: class.color,
        parts: class.parts.clone(),
        support: None,
    }
    .bounds()
}

/// A free-standing row of identical objects side by side, all facing one way.
fn place_free_row(file: &mut SceneFile, rng: &mut ChaCha8Rng, size: [f64; 3]) {
    let Some(name) = FREE_ROW_CLASSES.choose(rng).copied() else {
        return;
    };
    let Some(class) = library::class(name) else {
        return;
    };
    let scale = rng.random_range(0.95..1.05);
    let color = jitter_color(rng, class.color, 0.12);
    let gap = rng.random_range(0.0..0.1);
    let count = rng.random_range(2..=4);
    let yaw = rng.random_range(-180.0f64..180.0);
    let centre = [
        rng.random_range(1.0..size[0] - 1.0),
        rng.random_range(1.0..size[1] - 1.0),
    ];
    let (lo, hi) = placed_bounds(&class, 0.0, scale);
    let step = hi.x - lo.x + gap;
    let (c, s) = (yaw.to_radians().cos(), yaw.to_radians().sin());
    for k in 0..count {
        let offset = (k as f64 - (count as f64 - 1.0) / 2.0) * step;
        try_add(
            file,
            ObjectSpec {
                class: name.into(),
                position: [centre[0] + c * offset, centre[1] + s * offset],
                yaw_deg: yaw,
                scale,
                color: Some(color),
                on: None,
                surface: 0,
            },
        );
    }
}

/// A table with 2 or 3 identical chairs lined up along one long side, facing it.
fn place_table_with_a_row_of_chairs(file: &mut SceneFile, rng: &mut ChaCha8Rng, size: [f64; 3]) {
    let yaw = rng.random_range(-180.0f64..180.0);
    let centre = [
        rng.random_range(1.2..size[0] - 1.2),
        rng.random_range(1.2..size[1] - 1.2),
    ];
    let table = ObjectSpec {
        class: "table".into(),
        position: centre,
        yaw_deg: yaw,
        scale: 1.0,
        color: None,
        on: None,
        surface: 0,
    };
    if !try_add(file, table) {
        return;
    }
    let color = jitter_color(rng, [0.55, 0.35, 0.2], 0.1);
    let count = rng.random_range(2..=3);
    let side = if rng.random::<bool>() { 1.0 } else { -1.0 };
    let (c, s) = (yaw.to_radians().cos(), yaw.to_radians().sin());
    for k in 0..count {
        // Along the table's long local x, a chair's width apart, on one side of it.
        let x = (k as f64 - (count as f64 - 1.0) / 2.0) * 0.5;
        let y = side * 0.65;
        let facing = if side > 0.0 { yaw + 180.0 } else { yaw };
        try_add(
            file,
            ObjectSpec {
                class: "chair".into(),
                position: [centre[0] + c * x - s * y, centre[1] + s * x + c * y],
                yaw_deg: facing,
                scale: 1.0,
                color: Some(color),
                on: None,
                surface: 0,
            },
        );
    }
}

/// Chairs around tables, facing them.
fn place_chairs_at_tables(file: &mut SceneFile, rng: &mut ChaCha8Rng) {
    // Chairs around tables, facing them.
    let tables: Vec<usize> = (0..file.objects.len())
        .filter(|&i| file.objects[i].class == "table")
        .collect();
    for table in tables {
        let chairs = rng.random_range(0..=2);
        let color = jitter_color(rng, [0.55, 0.35, 0.2], 0.1);
        for _ in 0..chairs {
            for _ in 0..10 {
                let t = &file.objects[table];
                let angle = rng.random_range(0.0..std::f64::consts::TAU);
                let distance = 0.75 * t.scale + rng.random_range(0.0..0.3);
                let position = [
                    t.position[0] + distance * angle.cos(),
                    t.position[1] + distance * angle.sin(),
                ];
                // The seat faces local +y (the backrest is at -y).
                let facing = (angle + std::f64::consts::PI).to_degrees() - 90.0;
                let spec = ObjectSpec {
                    class: "chair".into(),
                    position,
                    yaw_deg: facing,
                    scale: rng.random_range(0.95..1.05),
                    color: Some(color),
                    on: None,
                    surface: 0,
                };
                if try_add(file, spec) {
                    break;
                }
            }
        }
    }
}

/// Small objects on the surfaces that carry them.
fn place_small_objects(file: &mut SceneFile, rng: &mut ChaCha8Rng) {
    // Small objects on the surfaces that carry them.
    let supports: Vec<usize> = (0..file.objects.len()).collect();
    let classes = library::classes();
    for support in supports {
        let support_spec = file.objects[support].clone();
        let Some(support_class) = library::class(&support_spec.class) else {
            continue;
        };
        if support_class.surfaces.is_empty() || rng.random::<f64>() < 0.35 {
            continue;
        }
        let candidates: Vec<&library::ObjectClass> = classes
            .iter()
            .filter(|c| match c.placement {
                Placement::OnTopOf { supports, .. } => supports.contains(&support_class.name),
                Placement::Floor => false,
            })
            .collect();
        let items = rng.random_range(1..=3);
        for _ in 0..items {
            let Some(item) = candidates.choose(rng) else {
                break;
            };
            let surface_index = rng.random_range(0..support_class.surfaces.len());
            let surface = support_class.surfaces[surface_index];
            for _ in 0..12 {
                let local = glam::DVec3::new(
                    surface.center[0] + rng.random_range(-surface.half[0]..surface.half[0]),
                    surface.center[1] + rng.random_range(-surface.half[1]..surface.half[1]),
                    0.0,
                ) * support_spec.scale;
                let world = glam::DQuat::from_rotation_z(support_spec.yaw_deg.to_radians()) * local;
                let spec = ObjectSpec {
                    class: item.name.into(),
                    position: [
                        support_spec.position[0] + world.x,
                        support_spec.position[1] + world.y,
                    ],
                    yaw_deg: support_spec.yaw_deg + rng.random_range(-20.0..20.0),
                    scale: rng.random_range(library::SCALE_RANGE.0..library::SCALE_RANGE.1),
                    color: Some(jitter_color(rng, item.color, 0.12)),
                    on: Some(support),
                    surface: surface_index,
                };
                if try_add(file, spec) {
                    break;
                }
            }
        }
    }
}

/// The robot: a random walk from a free spot, facing the room's centre.
fn place_robot(
    mut file: SceneFile,
    rng: &mut ChaCha8Rng,
    size: [f64; 3],
    options: &ProceduralOptions,
) -> Option<SceneFile> {
    // The robot: a random walk from a free spot, facing the room's centre. A room too full to
    // stand in loses floor objects (that carry nothing) until there is room.
    let start = loop {
        let scene = file.build().ok()?;
        let random = (0..200).find_map(|_| {
            let p = glam::DVec3::new(
                rng.random_range(0.0..size[0]),
                rng.random_range(0.0..size[1]),
                0.0,
            );
            is_free(&scene, p).then_some(p)
        });
        let grid = || {
            (0..(size[0] * 10.0) as usize)
                .flat_map(|i| (0..(size[1] * 10.0) as usize).map(move |j| (i, j)))
                .map(|(i, j)| glam::DVec3::new(i as f64 / 10.0, j as f64 / 10.0, 0.0))
                .find(|p| is_free(&scene, *p))
        };
        if let Some(p) = random.or_else(grid) {
            break p;
        }
        let carried: Vec<usize> = file.objects.iter().filter_map(|o| o.on).collect();
        let removable = (0..file.objects.len())
            .rev()
            .find(|&i| file.objects[i].on.is_none() && !carried.contains(&i))?;
        file.objects.remove(removable);
        // Indices of supports after the removed object shift down by one.
        for object in &mut file.objects {
            if let Some(on) = object.on.as_mut() {
                if *on > removable {
                    *on -= 1;
                }
            }
        }
    };
    let to_center = (size[1] / 2.0 - start.y).atan2(size[0] / 2.0 - start.x);
    file.trajectory = Trajectory::RandomWalk {
        start: [start.x, start.y, to_center.to_degrees()],
        frames: options.frames,
        rate_hz: options.rate_hz,
        speed: 0.3,
        turn_deg: 6.0,
    };
    Some(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_seed_ranges_are_disjoint_and_bounded() {
        let mut seen = std::collections::BTreeSet::new();
        for split in Split::ALL {
            for index in [0, 1, 999, Split::CAPACITY - 1] {
                assert!(seen.insert(split.seed(index).unwrap()), "{split} {index}");
            }
            assert!(split.seed(Split::CAPACITY).is_none());
            assert_eq!(Split::parse(split.name()), Some(split));
        }
    }

    #[test]
    fn generation_is_deterministic_and_splits_differ() {
        assert_eq!(generate(Split::Train, 3), generate(Split::Train, 3));
        assert_ne!(
            generate(Split::Train, 3).unwrap().objects,
            generate(Split::Val, 3).unwrap().objects
        );
    }
}
