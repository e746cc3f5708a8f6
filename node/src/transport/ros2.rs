//! Native ROS 2 transport through r2r (rcl with the middleware ROS is configured for; the PyPI
//! wheels that `make ros2` installs bring rmw_fastrtps).
//!
//! It moves serialized messages like the zenoh transport: topics go through r2r's raw
//! subscriptions and publishers, so the bytes on the wire are the node's own CDR (the same
//! encoders feed both transports). rcl serves services only with a generated type, so each
//! service type the node serves is named below; its requests are serialized by rcl, handed to
//! the node's handler as CDR, and the CDR answer is deserialized into the typed response.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use futures::executor::ThreadPool;
use futures::StreamExt;
use groupforward_msgs::rmw_zenoh::Qos;
use groupforward_msgs::services::{GetInstance, ListInstances, LoadMap, Refer, SaveMap};
use groupforward_msgs::RosService;
use r2r::{QosProfile, WrappedServiceTypeSupport, WrappedTypesupport};

use super::{
    log_request_failure, Endpoint, JsonHandler, Publisher, Result, ServiceHandler, Sink, Transport,
    TransportError,
};

/// How long one `spin_once` may hold the node: calls that declare entities wait at most this.
const SPIN_SLICE: Duration = Duration::from_millis(5);
/// Threads that run subscription sinks and service handlers (a handler may take tens of ms to
/// answer a referring query; sinks only push to the input queue).
const EXECUTOR_THREADS: usize = 3;

fn rerr(e: impl std::fmt::Display) -> TransportError {
    TransportError::Ros2(e.to_string())
}

/// The node's QoS as rcl's profile.
pub fn qos_profile(qos: &Qos) -> QosProfile {
    let mut profile = QosProfile::default();
    profile = if qos.keep_all {
        profile.keep_all()
    } else {
        profile.keep_last(qos.depth.max(1) as usize)
    };
    profile = if qos.best_effort {
        profile.best_effort()
    } else {
        profile.reliable()
    };
    if qos.transient_local {
        profile.transient_local()
    } else {
        profile.volatile()
    }
}

/// One r2r node, spun on its own thread.
pub struct Ros2Transport {
    node: Arc<Mutex<r2r::Node>>,
    executor: ThreadPool,
    stop: Arc<AtomicBool>,
    spinner: Option<JoinHandle<()>>,
    name: String,
}

impl std::fmt::Debug for Ros2Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Ros2Transport({})", self.name)
    }
}

impl Ros2Transport {
    /// Create node `name` in `namespace` (rcl reads ROS_DOMAIN_ID and the middleware from the
    /// environment, as every ROS 2 node does).
    pub fn new(namespace: &str, name: &str) -> Result<Self> {
        let rcl = |e: r2r::Error| {
            TransportError::Ros2(format!(
                "creating the rcl node (is the ROS 2 environment set up? launch/ros2/env.sh): {e}"
            ))
        };
        let context = r2r::Context::create().map_err(rcl)?;
        let node = r2r::Node::create(context, name, namespace).map_err(rcl)?;
        let node = Arc::new(Mutex::new(node));
        let stop = Arc::new(AtomicBool::new(false));
        let spinner = {
            let (node, stop) = (node.clone(), stop.clone());
            std::thread::Builder::new()
                .name("gf-ros2-spin".into())
                .spawn(move || {
                    while !stop.load(Ordering::Relaxed) {
                        match node.lock() {
                            Ok(mut node) => node.spin_once(SPIN_SLICE),
                            Err(_) => return,
                        }
                        // Let a thread waiting to declare an entity take the lock.
                        std::thread::yield_now();
                    }
                })
                .map_err(rerr)?
        };
        let executor = ThreadPool::builder()
            .pool_size(EXECUTOR_THREADS)
            .name_prefix("gf-ros2-")
            .create()
            .map_err(rerr)?;
        Ok(Self {
            node,
            executor,
            stop,
            spinner: Some(spinner),
            name: format!("{}/{name}", namespace.trim_end_matches('/')),
        })
    }

    fn with_node<T>(&self, f: impl FnOnce(&mut r2r::Node) -> r2r::Result<T>) -> Result<T> {
        let mut node = self
            .node
            .lock()
            .map_err(|_| TransportError::Ros2("node lock poisoned".into()))?;
        f(&mut node).map_err(rerr)
    }

    /// Serve a service of generated type `S` with a handler that speaks CDR.
    fn serve_typed<S>(&self, service: &Endpoint, handler: ServiceHandler) -> Result<()>
    where
        S: WrappedServiceTypeSupport + 'static,
    {
        let mut requests = self
            .with_node(|node| node.create_service::<S>(&service.name, qos_profile(&service.qos)))?;
        let name = service.name.clone();
        let failures = AtomicU64::new(0);
        self.executor.spawn_ok(async move {
            while let Some(request) = requests.next().await {
                let response = answer::<S>(&request.message, &handler).unwrap_or_else(|message| {
                    log_request_failure(&failures, &name, &message);
                    failed_response::<S::Response>(&message)
                });
                if let Err(e) = request.respond(response) {
                    tracing::warn!(service = %name, "cannot send reply: {e}");
                }
            }
        });
        Ok(())
    }
}

/// The handler's answer to one typed request, through the node's CDR.
fn answer<S: WrappedServiceTypeSupport>(
    request: &S::Request,
    handler: &ServiceHandler,
) -> std::result::Result<S::Response, String> {
    let cdr = request.to_serialized_bytes().map_err(|e| e.to_string())?;
    let reply = handler(&cdr)?;
    S::Response::from_serialized_bytes(&reply).map_err(|e| format!("answer does not decode: {e}"))
}

/// ROS 2 services have no error reply: a failed request is answered with the default response,
/// `success` false and the reason in `message` where the type has those fields.
pub fn failed_response<R: WrappedTypesupport>(message: &str) -> R {
    let mut value = serde_json::to_value(R::default()).unwrap_or_default();
    if let Some(fields) = value.as_object_mut() {
        if fields.contains_key("success") {
            fields.insert("success".into(), false.into());
        }
        if fields.contains_key("message") {
            fields.insert("message".into(), message.into());
        }
    }
    serde_json::from_value(value).unwrap_or_default()
}

impl Drop for Ros2Transport {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(spinner) = self.spinner.take() {
            let _ = spinner.join();
        }
    }
}

struct Ros2Publisher {
    publisher: Mutex<r2r::PublisherUntyped>,
}

impl Publisher for Ros2Publisher {
    fn publish(&self, payload: &[u8]) -> Result<()> {
        let publisher = self
            .publisher
            .lock()
            .map_err(|_| TransportError::Ros2("publisher lock poisoned".into()))?;
        publisher.publish_raw(payload).map_err(rerr)
    }
}

impl Transport for Ros2Transport {
    fn subscribe(&self, topic: &Endpoint, sink: Sink) -> Result<()> {
        let mut messages = self.with_node(|node| {
            node.subscribe_raw(&topic.name, &topic.type_name, qos_profile(&topic.qos))
        })?;
        let topic_name = topic.name.clone();
        self.executor.spawn_ok(async move {
            while let Some(payload) = messages.next().await {
                tracing::trace!(topic = %topic_name, bytes = payload.len(), "received");
                sink(payload);
            }
        });
        Ok(())
    }

    fn advertise(&self, topic: &Endpoint) -> Result<Box<dyn Publisher>> {
        let publisher = self.with_node(|node| {
            node.create_publisher_untyped(&topic.name, &topic.type_name, qos_profile(&topic.qos))
        })?;
        Ok(Box::new(Ros2Publisher {
            publisher: Mutex::new(publisher),
        }))
    }

    fn serve(&self, service: &Endpoint, handler: ServiceHandler) -> Result<()> {
        use r2r::groupforward_msgs::srv;
        match service.type_name.as_str() {
            t if t == Refer::TYPE_NAME => self.serve_typed::<srv::Refer::Service>(service, handler),
            t if t == SaveMap::TYPE_NAME => {
                self.serve_typed::<srv::SaveMap::Service>(service, handler)
            }
            t if t == LoadMap::TYPE_NAME => {
                self.serve_typed::<srv::LoadMap::Service>(service, handler)
            }
            t if t == ListInstances::TYPE_NAME => {
                self.serve_typed::<srv::ListInstances::Service>(service, handler)
            }
            t if t == GetInstance::TYPE_NAME => {
                self.serve_typed::<srv::GetInstance::Service>(service, handler)
            }
            other => Err(TransportError::Ros2(format!(
                "service type {other} is not built into the ROS 2 transport"
            ))),
        }
    }

    /// The JSON API is zenoh's (a queryable per name); a ROS 2 graph has the typed services.
    fn serve_json(&self, prefix: &str, _handler: JsonHandler) -> Result<()> {
        tracing::info!(
            %prefix,
            "JSON API not served on the ROS 2 transport (use the services, or transport: zenoh)"
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    //! The node's CDR against rcl's own serializers (rosidl_typesupport_fastrtps): what the node
    //! writes, rcl reads and writes back byte for byte, and what rcl writes, the node reads.
    use super::*;
    use groupforward_msgs::builtin_interfaces::Time;
    use groupforward_msgs::cdr;
    use groupforward_msgs::geometry_msgs::{Pose, TransformStamped};
    use groupforward_msgs::gf_msgs::{ReferRequest, ReferResponse};
    use groupforward_msgs::sensor_msgs::Image;
    use groupforward_msgs::std_msgs::Header;
    use groupforward_msgs::tf2_msgs::TFMessage;
    use groupforward_msgs::vision_msgs::BoundingBox3D;

    /// rcl decodes the node's encoding of `value` and encodes it again to the same layout: the
    /// same length, and bytes the node decodes to `value` (CDR leaves padding unspecified, and
    /// rcl's serializer leaves whatever its buffer held there, so padding is not compared).
    fn rcl_round_trip<R, T>(value: &T) -> R
    where
        R: WrappedTypesupport,
        T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
    {
        let ours = cdr::encode(value).unwrap();
        let theirs = R::from_serialized_bytes(&ours).expect("rcl decodes the node's CDR");
        let back = theirs.to_serialized_bytes().expect("rcl encodes");
        assert_eq!(
            back.len(),
            ours.len(),
            "rcl's layout differs for {theirs:?}"
        );
        let decoded: T = cdr::decode(&back).expect("the node decodes rcl's CDR");
        assert_eq!(&decoded, value);
        theirs
    }

    fn header() -> Header {
        Header {
            stamp: Time {
                sec: 1_700_000_000,
                nanosec: 123_456_789,
            },
            frame_id: "camera_color_optical_frame".into(),
        }
    }

    #[test]
    fn an_image_the_node_encodes_is_what_rcl_encodes() {
        let image = Image {
            header: header(),
            height: 2,
            width: 3,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 9,
            data: (0..18).collect(),
        };
        let theirs: r2r::sensor_msgs::msg::Image = rcl_round_trip(&image);
        assert_eq!((theirs.width, theirs.height, theirs.step), (3, 2, 9));
        assert_eq!(theirs.header.frame_id, "camera_color_optical_frame");
        assert_eq!(theirs.data, image.data);
    }

    #[test]
    fn tf_messages_from_rcl_decode_in_the_node() {
        let mut transform = r2r::geometry_msgs::msg::TransformStamped::default();
        transform.header.frame_id = "map".into();
        transform.child_frame_id = "camera_link".into();
        transform.transform.translation.x = 1.5;
        transform.transform.rotation.w = 1.0;
        let theirs = r2r::tf2_msgs::msg::TFMessage {
            transforms: vec![transform.clone(), transform],
        };
        let ours: TFMessage = cdr::decode(&theirs.to_serialized_bytes().unwrap()).unwrap();
        assert_eq!(ours.transforms.len(), 2);
        let first: &TransformStamped = &ours.transforms[0];
        assert_eq!(first.child_frame_id, "camera_link");
        assert_eq!(first.transform.translation.x, 1.5);
        rcl_round_trip::<r2r::tf2_msgs::msg::TFMessage, _>(&ours);
    }

    #[test]
    fn a_refer_exchange_matches_rcl_both_ways() {
        let request = ReferRequest {
            expression: "the trash bin near the cabinet".into(),
            use_view_pose: true,
            view_pose: Pose::default(),
            max_targets: 1,
            reasoner: "builtin".into(),
        };
        use r2r::groupforward_msgs::srv::Refer as RclRefer;
        let theirs: RclRefer::Request = rcl_round_trip(&request);
        assert_eq!(theirs.expression, request.expression);
        let response = ReferResponse {
            success: true,
            message: "1 target".into(),
            instance_ids: vec!["inst_0007".into()],
            confidences: vec![0.8],
            poses: vec![Pose::default()],
            boxes: vec![BoundingBox3D::default()],
            reasoner_used: "builtin".into(),
            trace: "parsed".into(),
            ..ReferResponse::default()
        };
        let theirs: RclRefer::Response = rcl_round_trip(&response);
        assert_eq!(theirs.instance_ids, vec!["inst_0007".to_owned()]);
        assert_eq!(theirs.confidences, vec![0.8]);
    }

    #[test]
    fn what_the_node_publishes_decodes_in_rcl() {
        use groupforward_msgs::gf_msgs::{CameraStatus, NodeStatus, RejectCount};
        use groupforward_msgs::vision_msgs::{Detection3D, Detection3DArray};
        let status = NodeStatus {
            header: header(),
            uptime_secs: 12.5,
            cameras: vec![CameraStatus {
                name: "front".into(),
                frames_received: 40,
                rate_hz: 9.5,
                ..CameraStatus::default()
            }],
            tf_received: 41,
            rejections: vec![RejectCount {
                reason: "no_pose".into(),
                count: 3,
            }],
            ..NodeStatus::default()
        };
        let theirs: r2r::groupforward_msgs::msg::NodeStatus = rcl_round_trip(&status);
        assert_eq!(theirs.cameras[0].frames_received, 40);
        assert_eq!(theirs.rejections[0].reason, "no_pose");
        let detections = Detection3DArray {
            header: header(),
            detections: vec![Detection3D {
                header: header(),
                id: "inst_000001".into(),
                ..Detection3D::default()
            }],
        };
        let theirs: r2r::vision_msgs::msg::Detection3DArray = rcl_round_trip(&detections);
        assert_eq!(theirs.detections[0].id, "inst_000001");
    }

    #[test]
    fn a_failed_request_answers_success_false_with_the_reason() {
        use r2r::groupforward_msgs::srv::{ListInstances as RclList, Refer as RclRefer};
        let refused: RclRefer::Response = failed_response("rate limited");
        assert!(!refused.success);
        assert_eq!(refused.message, "rate limited");
        // A response without those fields is the default one.
        let empty: RclList::Response = failed_response("rate limited");
        assert!(empty.instances.is_empty());
    }

    #[test]
    fn qos_maps_reliability_durability_and_history() {
        let sensor = qos_profile(&Qos::sensor_data());
        assert_eq!(sensor.reliability, r2r::qos::ReliabilityPolicy::BestEffort);
        assert_eq!(sensor.depth, 5);
        let latched = qos_profile(&Qos {
            transient_local: true,
            depth: 1,
            ..Qos::default()
        });
        assert_eq!(
            latched.durability,
            r2r::qos::DurabilityPolicy::TransientLocal
        );
        assert_eq!(latched.reliability, r2r::qos::ReliabilityPolicy::Reliable);
        assert_eq!(latched.depth, 1);
    }
}
