//! The versioned envelope around every payload: two magic bytes `FL`, the
//! protocol version, then the postcard encoding of the message. Decoding
//! never panics: bad magic, another version, a truncated or malformed body
//! and trailing bytes are each a distinct [`EnvelopeError`].

// A codec reads bytes from outside: no index may panic.
#![warn(clippy::indexing_slicing)]

use crate::mms::pdu::PROTOCOL_VERSION;
use serde::{de::DeserializeOwned, Serialize};

const MAGIC: [u8; 2] = *b"FL";

/// Why a payload could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EnvelopeError {
    /// Shorter than the 3-byte header.
    #[error("payload of {0} bytes is shorter than the 3-byte envelope header")]
    TooShort(usize),
    /// Not a FALC envelope.
    #[error("payload does not start with the FALC envelope magic `FL` (found {0:02x?})")]
    BadMagic([u8; 2]),
    /// Another protocol version.
    #[error("envelope version {found} is not supported (this node speaks {supported})")]
    Version {
        /// The version in the payload.
        found: u8,
        /// The version this build speaks.
        supported: u8,
    },
    /// The body is not a valid message of the expected type.
    #[error("malformed message body: {0}")]
    Body(String),
    /// Bytes left over after the message.
    #[error("{0} unexpected bytes after the message")]
    Trailing(usize),
}

/// Encodes a message into an envelope.
pub fn encode<T: Serialize>(message: &T) -> Vec<u8> {
    let out = vec![MAGIC[0], MAGIC[1], PROTOCOL_VERSION];
    // postcard's serializer into a Vec fails only for types serde cannot
    // express (maps with unknown length and the like), which ours never are.
    match postcard::to_extend(message, out) {
        Ok(v) => v,
        Err(e) => unreachable!("FALC messages always serialize: {e}"),
    }
}

/// Decodes an envelope.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, EnvelopeError> {
    let [m0, m1, version, body @ ..] = bytes else {
        return Err(EnvelopeError::TooShort(bytes.len()));
    };
    if [*m0, *m1] != MAGIC {
        return Err(EnvelopeError::BadMagic([*m0, *m1]));
    }
    if *version != PROTOCOL_VERSION {
        return Err(EnvelopeError::Version {
            found: *version,
            supported: PROTOCOL_VERSION,
        });
    }
    let (message, rest) =
        postcard::take_from_bytes(body).map_err(|e| EnvelopeError::Body(e.to_string()))?;
    if !rest.is_empty() {
        return Err(EnvelopeError::Trailing(rest.len()));
    }
    Ok(message)
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    use crate::ids::ObjectName;
    use crate::mms::error::ServiceError;
    use crate::mms::pdu::{Request, Response};
    use proptest::prelude::*;

    #[test]
    fn round_trips() {
        let r = Request::Start {
            name: ObjectName::new("droog_dik").expect("valid"),
            argument: "order 7".into(),
        };
        assert_eq!(decode::<Request>(&encode(&r)), Ok(r));
        let e = ServiceError::unreachable("x");
        assert_eq!(decode::<ServiceError>(&encode(&e)), Ok(e));
    }

    #[test]
    fn names_what_is_wrong() {
        assert_eq!(decode::<Request>(b"F"), Err(EnvelopeError::TooShort(1)));
        assert_eq!(
            decode::<Request>(b"XX\x01\x00"),
            Err(EnvelopeError::BadMagic(*b"XX"))
        );
        assert_eq!(
            decode::<Request>(b"FL\x07\x00"),
            Err(EnvelopeError::Version {
                found: 7,
                supported: PROTOCOL_VERSION
            })
        );
        assert!(matches!(
            decode::<Request>(b"FL\x02\xff"),
            Err(EnvelopeError::Body(_))
        ));
        let mut extra = encode(&Request::Status);
        extra.push(0);
        assert_eq!(decode::<Request>(&extra), Err(EnvelopeError::Trailing(1)));
        // An invalid station name inside is a body error, not a panic.
        let mut bad = encode(&Request::Initiate {
            calling: crate::mms::pdu::Peer {
                station: crate::ids::StationName::new("cell").expect("valid"),
                session: "1".into(),
            },
        });
        let at = bad
            .iter()
            .position(|&b| b == b'c')
            .expect("name in payload");
        bad[at] = b'*';
        assert!(matches!(
            decode::<Request>(&bad),
            Err(EnvelopeError::Body(_))
        ));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]
        #[test]
        fn never_panics_on_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            let _ = decode::<Request>(&bytes);
            let _ = decode::<Response>(&bytes);
            let _ = decode::<ServiceError>(&bytes);
            let _ = decode::<crate::mms::pdu::Unconfirmed>(&bytes);
            let _ = decode::<crate::mms::journal::Publication>(&bytes);
            let _ = decode::<crate::mms::journal::KeptReports>(&bytes);
        }

        #[test]
        fn never_panics_behind_a_valid_header(body in proptest::collection::vec(any::<u8>(), 0..256)) {
            let mut bytes = b"FL\x02".to_vec();
            bytes.extend(body);
            let _ = decode::<Request>(&bytes);
            let _ = decode::<Response>(&bytes);
            let _ = decode::<ServiceError>(&bytes);
        }
    }
}
