//! Naming conventions of ROS 2's rmw_zenoh (Jazzy and later), so a ROS 2 system running rmw_zenoh
//! sees this node's topics and services natively.
//!
//! - Data key: `<domain>/<topic without outer slashes>/<pkg>::msg::dds_::<Type>_/RIHS01_<hash>`;
//!   services the same with `srv` (the service's type and hash, not its request's).
//! - Liveliness tokens announce the node and each entity:
//!   `@ros2_lv/<domain>/<zid>/<nid>/<eid>/<NN|MP|MS|SS|SC>/<enclave>/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]`
//!   with every `/` inside a name mangled to `%`.
//! - Every sample and service request / reply carries an attachment: i64 LE sequence number,
//!   i64 LE source timestamp (ns), then the 16-byte source gid prefixed by its length (u8 16), the
//!   layout of zenoh-ext's serializer.

use sha2::{Digest, Sha256};

pub const ADMIN_SPACE: &str = "@ros2_lv";
pub const GID_SIZE: usize = 16;
const ATTACHMENT_SIZE: usize = 8 + 8 + 1 + GID_SIZE;

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum NamingError {
    #[error("invalid ROS name `{0}`: {1}")]
    InvalidName(String, &'static str),
    #[error("type name `{0}` is not of the form pkg/msg/Name or pkg/srv/Name")]
    InvalidTypeName(String),
    #[error("attachment of {0} bytes, expected {ATTACHMENT_SIZE}")]
    AttachmentSize(usize),
    #[error("attachment gid length byte is {0}, expected {GID_SIZE}")]
    AttachmentGidLength(u8),
}

pub type Result<T> = std::result::Result<T, NamingError>;

/// Entity kinds as liveliness tokens spell them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    Node,
    Publisher,
    Subscription,
    ServiceServer,
    ServiceClient,
}

impl EntityKind {
    pub fn token_str(self) -> &'static str {
        match self {
            Self::Node => "NN",
            Self::Publisher => "MP",
            Self::Subscription => "MS",
            Self::ServiceServer => "SS",
            Self::ServiceClient => "SC",
        }
    }
}

/// `sensor_msgs/msg/Image` → `sensor_msgs::msg::dds_::Image_`.
pub fn dds_type_name(type_name: &str) -> Result<String> {
    match type_name.split('/').collect::<Vec<_>>().as_slice() {
        [pkg, kind @ ("msg" | "srv"), name] if !pkg.is_empty() && !name.is_empty() => {
            Ok(format!("{pkg}::{kind}::dds_::{name}_"))
        }
        _ => Err(NamingError::InvalidTypeName(type_name.to_owned())),
    }
}

/// Replace `/` by `%`, as rmw_zenoh does for names inside liveliness tokens.
pub fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// Check a fully qualified ROS name (`/a/b_c`): absolute, no empty or bad tokens.
pub fn validate_fqn(name: &str) -> Result<()> {
    let bad = |why| Err(NamingError::InvalidName(name.to_owned(), why));
    if !name.starts_with('/') {
        return bad("must be absolute");
    }
    if name == "/" {
        return Ok(());
    }
    for token in name[1..].split('/') {
        if token.is_empty() {
            return bad("empty token (double or trailing slash)");
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            return bad("a token starts with a digit");
        }
        if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return bad("only letters, digits and underscores are allowed");
        }
    }
    Ok(())
}

/// Resolve a topic or service name against a node's namespace and name, as rcl does:
/// `~/x` → `<ns>/<node>/x`, `x` → `<ns>/x`, `/x` stays.
pub fn resolve_name(namespace: &str, node: &str, name: &str) -> Result<String> {
    let ns = namespace.trim_end_matches('/');
    let resolved = if let Some(rest) = name.strip_prefix("~/") {
        format!("{ns}/{node}/{rest}")
    } else if name == "~" {
        format!("{ns}/{node}")
    } else if name.starts_with('/') {
        name.to_owned()
    } else {
        format!("{ns}/{name}")
    };
    validate_fqn(&resolved)?;
    Ok(resolved)
}

/// The data key expression of a topic or service.
pub fn data_key(domain_id: u32, fqn: &str, type_name: &str, type_hash: &str) -> Result<String> {
    validate_fqn(fqn)?;
    let topic = fqn.trim_matches('/');
    Ok(format!(
        "{domain_id}/{topic}/{}/{type_hash}",
        dds_type_name(type_name)?
    ))
}

/// ROS 2 QoS as rmw_zenoh encodes it in liveliness tokens. Fields equal to rmw_zenoh's defaults
/// (reliable, volatile, keep-last, infinite durations) are written as empty strings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    pub best_effort: bool,
    pub transient_local: bool,
    pub keep_all: bool,
    pub depth: u32,
}

impl Default for Qos {
    fn default() -> Self {
        Self {
            best_effort: false,
            transient_local: false,
            keep_all: false,
            depth: 10,
        }
    }
}

impl Qos {
    /// ROS 2's sensor-data profile (best effort, depth 5).
    pub fn sensor_data() -> Self {
        Self {
            best_effort: true,
            depth: 5,
            ..Self::default()
        }
    }

    /// `<reliability>:<durability>:<history>,<depth>:<deadline>:<lifespan>:<liveliness>`.
    pub fn to_keyexpr(&self) -> String {
        // rmw enum values: RELIABILITY_BEST_EFFORT = 2, DURABILITY_TRANSIENT_LOCAL = 1,
        // HISTORY_KEEP_ALL = 2.
        let reliability = if self.best_effort { "2" } else { "" };
        let durability = if self.transient_local { "1" } else { "" };
        let history = if self.keep_all { "2" } else { "" };
        format!("{reliability}:{durability}:{history},{}:,:,:,,", self.depth)
    }
}

/// Identity of a node in the ROS graph.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeIdentity {
    pub domain_id: u32,
    /// The zenoh session id, as zenoh prints it.
    pub zid: String,
    /// Node id, unique within the session.
    pub node_id: u32,
    /// Absolute namespace, `/` for none.
    pub namespace: String,
    pub name: String,
    /// Security enclave, `/` for none.
    pub enclave: String,
}

impl NodeIdentity {
    fn prefix(&self, entity_id: u32, kind: EntityKind) -> String {
        format!(
            "{ADMIN_SPACE}/{}/{}/{}/{entity_id}/{}/{}/{}/{}",
            self.domain_id,
            self.zid,
            self.node_id,
            kind.token_str(),
            mangle(&self.enclave),
            mangle(&self.namespace),
            mangle(&self.name),
        )
    }

    /// The node's own liveliness token (entity id 0 like rmw_zenoh, kind `NN`).
    pub fn node_token(&self) -> String {
        self.prefix(0, EntityKind::Node)
    }

    /// A publisher / subscription / service token.
    pub fn entity_token(
        &self,
        entity_id: u32,
        kind: EntityKind,
        fqn: &str,
        type_name: &str,
        type_hash: &str,
        qos: &Qos,
    ) -> Result<String> {
        validate_fqn(fqn)?;
        Ok(format!(
            "{}/{}/{}/{}/{}",
            self.prefix(entity_id, kind),
            mangle(fqn),
            dds_type_name(type_name)?,
            type_hash,
            qos.to_keyexpr()
        ))
    }
}

/// A 16-byte entity gid derived from its liveliness token (unique per token, like rmw_zenoh's
/// xxhash of the same string; the exact hash function is private to each rmw).
pub fn gid_for_token(token: &str) -> [u8; GID_SIZE] {
    let digest = Sha256::digest(token.as_bytes());
    let mut gid = [0u8; GID_SIZE];
    gid.copy_from_slice(&digest[..GID_SIZE]);
    gid
}

/// The attachment rmw_zenoh puts on every sample, service request and reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    pub sequence_number: i64,
    pub source_timestamp: i64,
    pub source_gid: [u8; GID_SIZE],
}

impl Attachment {
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(ATTACHMENT_SIZE);
        out.extend_from_slice(&self.sequence_number.to_le_bytes());
        out.extend_from_slice(&self.source_timestamp.to_le_bytes());
        out.push(GID_SIZE as u8);
        out.extend_from_slice(&self.source_gid);
        out
    }

    pub fn decode(bytes: &[u8]) -> Result<Self> {
        if bytes.len() != ATTACHMENT_SIZE {
            return Err(NamingError::AttachmentSize(bytes.len()));
        }
        if bytes[16] as usize != GID_SIZE {
            return Err(NamingError::AttachmentGidLength(bytes[16]));
        }
        let mut i64_at = [0u8; 8];
        i64_at.copy_from_slice(&bytes[0..8]);
        let sequence_number = i64::from_le_bytes(i64_at);
        i64_at.copy_from_slice(&bytes[8..16]);
        let source_timestamp = i64::from_le_bytes(i64_at);
        let mut source_gid = [0u8; GID_SIZE];
        source_gid.copy_from_slice(&bytes[17..]);
        Ok(Self {
            sequence_number,
            source_timestamp,
            source_gid,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STRING_HASH: &str =
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18";

    #[test]
    fn data_keys_match_rmw_zenoh_design() {
        assert_eq!(
            data_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH).unwrap(),
            format!("0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
        );
        let hash = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a";
        assert_eq!(
            data_key(
                2,
                "/add_two_ints",
                "example_interfaces/srv/AddTwoInts",
                hash
            )
            .unwrap(),
            format!("2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{hash}")
        );
    }

    #[test]
    fn liveliness_tokens_match_rmw_zenoh_design() {
        let node = NodeIdentity {
            domain_id: 0,
            zid: "8b20917502ee955ac4476e0266340d5c".into(),
            node_id: 0,
            namespace: "/".into(),
            name: "talker".into(),
            enclave: "/".into(),
        };
        assert_eq!(
            node.node_token(),
            "@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/0/NN/%/%/talker"
        );
        let qos = Qos {
            depth: 7,
            ..Qos::default()
        };
        assert_eq!(
            node.entity_token(
                10,
                EntityKind::Publisher,
                "/chatter",
                "std_msgs/msg/String",
                STRING_HASH,
                &qos
            )
            .unwrap(),
            format!("@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,")
        );
        assert_eq!(Qos::sensor_data().to_keyexpr(), "2::,5:,:,:,,");
    }

    #[test]
    fn name_resolution() {
        assert_eq!(
            resolve_name("/", "groupforward", "~/status").unwrap(),
            "/groupforward/status"
        );
        assert_eq!(
            resolve_name("/robot1", "gf", "camera/image").unwrap(),
            "/robot1/camera/image"
        );
        assert_eq!(resolve_name("/r", "gf", "/tf").unwrap(), "/tf");
        assert!(resolve_name("/", "gf", "a//b").is_err());
        assert!(resolve_name("/", "gf", "1abc").is_err());
        assert!(resolve_name("/", "gf", "a-b").is_err());
        assert!(dds_type_name("Image").is_err());
    }

    #[test]
    fn attachment_round_trip_and_rejects() {
        let a = Attachment {
            sequence_number: 7,
            source_timestamp: -3,
            source_gid: [9; GID_SIZE],
        };
        let bytes = a.encode();
        assert_eq!(bytes.len(), 33);
        assert_eq!(bytes[16], 16);
        assert_eq!(Attachment::decode(&bytes).unwrap(), a);
        assert!(Attachment::decode(&bytes[..32]).is_err());
        let mut bad = bytes.clone();
        bad[16] = 15;
        assert_eq!(
            Attachment::decode(&bad),
            Err(NamingError::AttachmentGidLength(15))
        );
    }

    #[test]
    fn gids_differ_per_token() {
        assert_ne!(gid_for_token("a"), gid_for_token("b"));
    }
}
