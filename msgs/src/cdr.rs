//! CDR (XCDR1) encoding as ROS 2 uses it: a 4-byte encapsulation header (`00 01 00 00` for
//! little-endian) followed by the plain CDR body, with alignment counted from the end of the header.
//!
//! Decoding never trusts a length field: every sequence and string length is checked against the
//! bytes that remain before anything is allocated (`cdr-encoding` does this), so garbage input is an
//! error, never a huge allocation or a panic.

use byteorder::{BigEndian, LittleEndian};
use serde::de::DeserializeOwned;
use serde::Serialize;

/// Little-endian plain CDR, the encapsulation every ROS 2 middleware writes.
pub const ENCAPSULATION_CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];
const ENCAPSULATION_CDR_BE: [u8; 2] = [0x00, 0x00];

#[derive(Debug, thiserror::Error)]
pub enum CdrError {
    #[error("payload of {0} bytes is shorter than the 4-byte encapsulation header")]
    TooShort(usize),
    #[error("unsupported encapsulation {0:02x} {1:02x} (only plain CDR, XCDR1, is supported)")]
    UnsupportedEncapsulation(u8, u8),
    #[error("malformed CDR body: {0}")]
    Malformed(String),
    #[error("{0} trailing bytes after the message")]
    TrailingBytes(usize),
    #[error("cannot encode: {0}")]
    Encode(String),
}

pub type Result<T> = std::result::Result<T, CdrError>;

/// Encode `value` with the little-endian encapsulation header.
pub fn encode<T: Serialize>(value: &T) -> Result<Vec<u8>> {
    let mut out = Vec::with_capacity(64);
    out.extend_from_slice(&ENCAPSULATION_CDR_LE);
    cdr_encoding::to_writer::<T, LittleEndian, _>(&mut out, value)
        .map_err(|e| CdrError::Encode(e.to_string()))?;
    Ok(out)
}

/// Decode a message that starts with an encapsulation header.
///
/// Up to 3 trailing bytes are allowed: some writers pad the body to a multiple of 4 bytes.
pub fn decode<T: DeserializeOwned>(payload: &[u8]) -> Result<T> {
    if payload.len() < 4 {
        return Err(CdrError::TooShort(payload.len()));
    }
    let body = &payload[4..];
    let (value, consumed) = match (payload[0], payload[1]) {
        (0x00, 0x01) => cdr_encoding::from_bytes::<T, LittleEndian>(body),
        (a, b) if [a, b] == ENCAPSULATION_CDR_BE => cdr_encoding::from_bytes::<T, BigEndian>(body),
        (a, b) => return Err(CdrError::UnsupportedEncapsulation(a, b)),
    }
    .map_err(|e| CdrError::Malformed(e.to_string()))?;
    let trailing = body.len() - consumed;
    if trailing > 3 {
        return Err(CdrError::TrailingBytes(trailing));
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::builtin_interfaces::Time;
    use crate::types::sensor_msgs::Image;
    use crate::types::std_msgs::Header;

    fn image() -> Image {
        Image {
            header: Header {
                stamp: Time {
                    sec: 12,
                    nanosec: 34,
                },
                frame_id: "cam".into(),
            },
            height: 2,
            width: 2,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: 2,
            data: vec![1, 2, 3, 4],
        }
    }

    #[test]
    fn header_and_alignment() {
        let bytes = encode(&image()).unwrap();
        assert_eq!(&bytes[..4], &ENCAPSULATION_CDR_LE);
        // sec, nanosec, then frame_id length 4 ("cam\0").
        assert_eq!(&bytes[4..16], &[12, 0, 0, 0, 34, 0, 0, 0, 4, 0, 0, 0]);
        assert_eq!(decode::<Image>(&bytes).unwrap(), image());
    }

    #[test]
    fn rejects_truncated_and_garbage() {
        let bytes = encode(&image()).unwrap();
        for cut in 0..bytes.len() {
            assert!(decode::<Image>(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        assert!(matches!(
            decode::<Image>(&[0x00, 0x07, 0, 0, 1]),
            Err(CdrError::UnsupportedEncapsulation(0, 7))
        ));
        let mut long = bytes.clone();
        long.extend_from_slice(&[0; 8]);
        assert!(matches!(
            decode::<Image>(&long),
            Err(CdrError::TrailingBytes(8))
        ));
    }

    #[test]
    fn huge_length_field_is_an_error_not_an_allocation() {
        let mut bytes = encode(&image()).unwrap();
        // The data length sits 4 bytes before the 4 data bytes at the end.
        let at = bytes.len() - 8;
        bytes[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode::<Image>(&bytes).is_err());
    }
}
