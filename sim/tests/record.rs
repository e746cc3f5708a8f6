#![allow(clippy::unwrap_used)]
//! Recorded bags hold what a robot records plus ground truth on `/gt/...`, every message
//! decodable, camera messages missing exactly for dropped frames.

use std::collections::BTreeMap;

use groupforward_msgs::cdr;
use groupforward_msgs::sensor_msgs::{CameraInfo, CompressedImage, Image};
use groupforward_msgs::tf2_msgs::TFMessage;
use groupforward_msgs::vision_msgs::Detection3DArray;
use groupforward_sim::effects::Effect;
use groupforward_sim::record::{
    record_to_dir, record_to_memory, ColorFormat, DepthFormat, RecordOptions,
};
use groupforward_sim::scene::SceneFile;
use groupforward_sim::simulation::Simulation;

fn sim(effects: Vec<Effect>) -> Simulation {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/two_chairs.toml");
    let mut file = SceneFile::load(&path).unwrap();
    file.cameras[0].width = 48;
    file.cameras[0].height = 36;
    file.effects = effects;
    Simulation::new(file).unwrap()
}

fn topics(bytes: &[u8]) -> BTreeMap<String, Vec<Vec<u8>>> {
    let mut out: BTreeMap<String, Vec<Vec<u8>>> = BTreeMap::new();
    for message in mcap::MessageStream::new(bytes).unwrap() {
        let message = message.unwrap();
        out.entry(message.channel.topic.clone())
            .or_default()
            .push(message.data.to_vec());
    }
    out
}

#[test]
fn a_clean_recording_holds_every_topic_and_decodes() {
    let sim = sim(Vec::new());
    let (bytes, summary) = record_to_memory(&sim, &RecordOptions::default()).unwrap();
    let frames = sim.frame_count();
    assert_eq!(summary.frames, frames);
    let topics = topics(&bytes);
    let names: Vec<&str> = topics.keys().map(String::as_str).collect();
    assert_eq!(
        names,
        [
            "/camera/color/camera_info",
            "/camera/color/image_raw",
            "/camera/depth/image_raw",
            "/gt/camera/class",
            "/gt/camera/depth",
            "/gt/camera/instance",
            "/gt/objects",
            "/gt/tf",
            "/tf",
            "/tf_static",
        ]
    );
    for (topic, messages) in &topics {
        let expected = if topic == "/tf_static" { 1 } else { frames };
        assert_eq!(messages.len(), expected, "{topic}");
    }
    let info: CameraInfo = cdr::decode(&topics["/camera/color/camera_info"][0]).unwrap();
    assert_eq!((info.width, info.height), (48, 36));
    assert_eq!(info.d, vec![0.0; 5]);
    let image: Image = cdr::decode(&topics["/camera/color/image_raw"][3]).unwrap();
    assert_eq!(image.data, sim.frame(3).views[0].truth.rgb);
    let objects: Detection3DArray = cdr::decode(&topics["/gt/objects"][0]).unwrap();
    assert_eq!(objects.detections.len(), sim.scene.objects.len());
    assert_eq!(
        objects.detections[1].results[0].hypothesis.class_id,
        "chair"
    );
    let statics: TFMessage = cdr::decode(&topics["/tf_static"][0]).unwrap();
    assert_eq!(
        statics.transforms[0].child_frame_id,
        "camera_color_optical_frame"
    );
    // Without drift, odometry is the truth.
    assert_eq!(topics["/tf"], topics["/gt/tf"]);
}

#[test]
fn effects_show_in_the_recording() {
    let sim = sim(vec![
        Effect::FrameDrops { probability: 0.25 },
        Effect::OdometryDrift {
            sigma_m: 0.05,
            sigma_yaw_deg: 1.0,
        },
        Effect::LensDistortion {
            k1: -0.1,
            k2: 0.01,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
        },
        Effect::DepthDropout {
            probability: 0.05,
            edge_m: 0.1,
        },
    ]);
    let options = RecordOptions {
        color: ColorFormat::Png,
        depth: DepthFormat::Millimetres16,
        ..RecordOptions::default()
    };
    let (bytes, summary) = record_to_memory(&sim, &options).unwrap();
    assert!(summary.dropped > 0 && summary.dropped < summary.frames);
    let topics = topics(&bytes);
    let kept = summary.frames - summary.dropped;
    assert_eq!(topics["/camera/color/image_raw/compressed"].len(), kept);
    assert_eq!(topics["/camera/depth/image_raw"].len(), kept);
    assert_eq!(topics["/gt/camera/instance"].len(), kept);
    assert_eq!(topics["/tf"].len(), summary.frames, "odometry keeps coming");
    assert_ne!(topics["/tf"], topics["/gt/tf"], "odometry drifts");
    let info: CameraInfo = cdr::decode(&topics["/camera/color/camera_info"][0]).unwrap();
    assert_eq!(info.d, vec![-0.1, 0.01, 0.0, 0.0, 0.0]);
    let png: CompressedImage =
        cdr::decode(&topics["/camera/color/image_raw/compressed"][0]).unwrap();
    let decoded = image::load_from_memory(&png.data).unwrap().to_rgb8();
    assert_eq!(decoded.dimensions(), (48, 36));
    let depth: Image = cdr::decode(&topics["/camera/depth/image_raw"][0]).unwrap();
    assert_eq!(depth.encoding, "16UC1");
    let zeros = depth.data.chunks(2).filter(|c| c == &[0, 0]).count();
    assert!(zeros > 0, "dropped depth is 0 in 16UC1");
}

#[test]
fn a_bag_directory_has_metadata_describing_its_messages() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("two_chairs");
    let sim = sim(Vec::new());
    let summary = record_to_dir(&sim, &RecordOptions::default(), &bag, &|_| {}).unwrap();
    let metadata = std::fs::read_to_string(bag.join("metadata.yaml")).unwrap();
    assert!(metadata.contains("storage_identifier: mcap"));
    assert!(metadata.contains("- two_chairs_0.mcap"));
    assert!(metadata.contains(&format!("message_count: {}", summary.messages)));
    assert!(
        metadata.contains("reliability: best_effort"),
        "sensor QoS recorded"
    );
    let bytes = std::fs::read(bag.join("two_chairs_0.mcap")).unwrap();
    let total: usize = topics(&bytes).values().map(Vec::len).sum();
    assert_eq!(total as u64, summary.messages);
}
