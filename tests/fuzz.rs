//! Random bytes into every text field, on the whole cell: for each text
//! field of the operator API and of the station services the nodes serve
//! each other, requests whose field holds random bytes (control
//! characters and terminal escapes, invalid UTF-8, lengths from 0 to
//! 200,000), spliced into an otherwise valid envelope, sent over the
//! router as the user whose role may make the call. Every one is answered;
//! the answer is a named error or a small acknowledgement, never longer
//! than [`MAX_ANSWER`] and never holding the bytes raw (a refusal quotes
//! at most 40 characters, escaped); whatever was stored comes out of
//! `falc journal` escaped; every node still runs, and an order runs to
//! done after. The seed is printed; `FUZZ_SEED=N` repeats a run.

use crate::support::rig::rig;
use falc_model::api::{ApiRequest, ApiResult};
use falc_model::envelope;
use falc_model::ids::ObjectName;
use falc_model::keys::KeySpace;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Request, Response};
use falc_model::mode::{CellMode, ManualAction};
use falc_model::recipe_file::RecipeFile;
use rand::{Rng, SeedableRng};
use std::time::Duration;

/// The longest answer to a request with a random field (documented in
/// docs/operator-guide.md, "Limits": a refusal is a line or two).
const MAX_ANSWER: usize = 1024;
/// Random values per field.
const CASES: usize = 60;

/// The stand-in a field holds before its bytes are spliced in.
const MARKS: [&str; 3] = ["qzqzqzqz.rcp", "qzqzqzqz", "QZQZQZQZ"];

fn varint(mut n: usize) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let byte = (n & 0x7f) as u8;
        n >>= 7;
        if n == 0 {
            out.push(byte);
            return out;
        }
        out.push(byte | 0x80);
    }
}

/// `message`'s envelope with its stand-in string replaced by `bytes`.
fn spliced<T: serde::Serialize>(message: &T, bytes: &[u8]) -> Vec<u8> {
    let enc = envelope::encode(message);
    for mark in MARKS {
        let mut pattern = varint(mark.len());
        pattern.extend_from_slice(mark.as_bytes());
        if let Some(at) = enc.windows(pattern.len()).position(|w| w == pattern) {
            let mut out = enc[..at].to_vec();
            out.extend(varint(bytes.len()));
            out.extend_from_slice(bytes);
            out.extend_from_slice(&enc[at + pattern.len()..]);
            return out;
        }
    }
    panic!("no stand-in in {enc:?}")
}

/// Random bytes of the kinds an attacker sends.
fn random_bytes(rng: &mut rand::rngs::StdRng) -> Vec<u8> {
    let len = match rng.gen_range(0..6) {
        0 => rng.gen_range(0..8),
        1 => rng.gen_range(8..64),
        2 => rng.gen_range(64..4_200),
        3 => rng.gen_range(4_200..70_000),
        4 => 200_000,
        _ => 41,
    };
    let mut out = Vec::with_capacity(len);
    while out.len() < len {
        match rng.gen_range(0..6) {
            0 => out.extend_from_slice(b"\x1b]0;owned\x07\x1b[2J"),
            1 => out.push(rng.gen_range(0..0x20)),
            2 => out.extend_from_slice(&[0xff, 0xc0, 0x80]),
            3 => out.extend_from_slice("ü€\u{202e}\n".as_bytes()),
            _ => out.push(rng.gen_range(b'A'..=b'z')),
        }
    }
    out.truncate(len);
    out
}

/// What an answer says, decoded: the refusal's text, or None for an
/// acceptance (an API reply, or a service's response).
fn refusal_of(bytes: &[u8], service: bool) -> Option<String> {
    let accepted = if service {
        envelope::decode::<Response>(bytes).map(|_| None)
    } else {
        envelope::decode::<ApiResult>(bytes).map(Result::err)
    };
    accepted.unwrap_or_else(|_| match envelope::decode::<ServiceError>(bytes) {
        Ok(e) => Some(e.description),
        Err(e) => panic!("an answer that is no envelope: {e}"),
    })
}

#[test]
fn random_bytes_in_every_text_field_are_refused_by_name_or_stored_escaped() {
    let seed: u64 = std::env::var("FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| rand::thread_rng().gen());
    println!("fuzz seed {seed} (FUZZ_SEED={seed} repeats this run)");
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let rig = rig("50");
    let st = |s: &str| falc_model::ids::StationName::new(s).expect("station");
    let mark = || MARKS[1].to_string();
    let name = || ObjectName::new(MARKS[2]).expect("name");
    let cell_file = || RecipeFile::new(st("cell"), MARKS[1]).expect("file");
    let operator = rig.cell.topology.root().name.clone();
    let keys = KeySpace::new(rig.cell.topology.cell().clone());
    // (user, field, request): API calls, each with one field marked.
    let api: Vec<(&str, &str, ApiRequest)> = vec![
        (
            "console",
            "OrderAdd.recipe",
            ApiRequest::OrderAdd {
                recipe: mark(),
                placement: Default::default(),
                count: 1,
            },
        ),
        (
            "console",
            "Answer.text",
            ApiRequest::Answer { text: mark() },
        ),
        (
            "console",
            "RecipeGet.file",
            ApiRequest::RecipeGet { file: cell_file() },
        ),
        (
            "engineer",
            "RecipePut.file",
            ApiRequest::RecipePut {
                file: cell_file(),
                text: "-1 | output x | | | 0\n".into(),
                base: None,
                message: String::new(),
            },
        ),
        (
            "engineer",
            "RecipePut.message",
            ApiRequest::RecipePut {
                file: RecipeFile::new(st("cell"), "fuzz").expect("file"),
                text: "-1 | output x | | | 0\n".into(),
                base: None,
                message: mark(),
            },
        ),
        (
            "console",
            "RecipeHistory.file",
            ApiRequest::RecipeHistory { file: cell_file() },
        ),
        (
            "engineer",
            "RecipeRollback.message",
            ApiRequest::RecipeRollback {
                file: RecipeFile::new(st("cell"), "dikdroog").expect("file"),
                version: 1,
                message: mark(),
            },
        ),
        (
            "engineer",
            "RecipePut.text",
            ApiRequest::RecipePut {
                file: RecipeFile::new(st("cell"), "fuzz").expect("file"),
                text: mark(),
                base: None,
                message: String::new(),
            },
        ),
        (
            "console",
            "Mode.stations",
            ApiRequest::Mode {
                mode: CellMode::Step,
                stations: vec![st(MARKS[1])],
            },
        ),
        (
            "console",
            "Step.station",
            ApiRequest::Step {
                station: Some(st(MARKS[1])),
                to: None,
            },
        ),
        (
            "maintainer",
            "Manual.station",
            ApiRequest::Manual {
                station: st(MARKS[1]),
                action: ManualAction::StartProgram,
            },
        ),
        (
            "maintainer",
            "Manual.Press",
            ApiRequest::Manual {
                station: st("transport"),
                action: ManualAction::Press(mark()),
            },
        ),
    ];
    // (caller, target, field, request): station services.
    let services: Vec<(&str, &str, &str, Request)> = vec![
        (
            "operator",
            "cell",
            "Start.name",
            Request::Start {
                name: name(),
                argument: "order 1".into(),
            },
        ),
        (
            "operator",
            "cell",
            "Start.argument",
            Request::Start {
                name: ObjectName::new("NO_SUCH").expect("name"),
                argument: mark(),
            },
        ),
        (
            "operator",
            "cell",
            "GetDomainAttributes.domain",
            Request::GetDomainAttributes { domain: name() },
        ),
        (
            "cell",
            "operator",
            "Output.lines",
            Request::Output {
                lines: vec![mark()],
            },
        ),
    ];
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    let mut sent = 0usize;
    let mut accepted = 0usize;
    let mut largest = 0usize;
    let mut check = |field: &str, bytes: &[u8], answer: Option<Vec<u8>>, service: bool| {
        let answer = answer
            .unwrap_or_else(|| panic!("{field} with {} random bytes: no answer", bytes.len()));
        largest = largest.max(answer.len());
        assert!(
            answer.len() <= MAX_ANSWER,
            "{field} with {} random bytes: an answer of {} bytes",
            bytes.len(),
            answer.len()
        );
        match refusal_of(&answer, service) {
            Some(text) => {
                // Line breaks of its own (a list of recipe problems) only.
                assert!(
                    !text.chars().any(|c| c.is_control() && c != '\n'),
                    "{field}: a refusal with a raw control character: {text:?}"
                );
                if bytes.len() > 40 {
                    let head = String::from_utf8_lossy(&bytes[..41]);
                    assert!(!text.contains(head.as_ref()), "{field}: echoed: {text:?}");
                }
            }
            None => accepted += 1,
        }
        sent += 1;
    };
    rt.block_on(async {
        let mut sessions = std::collections::BTreeMap::new();
        for user in ["console", "engineer", "maintainer", "operator", "cell"] {
            sessions.insert(user, rig.cell.bus(user).await.expect("session"));
        }
        let ask = |bus: &falc_bus::Bus, key: String, payload: Vec<u8>| {
            let session = bus.session().clone();
            async move {
                let replies = session
                    .get(&key)
                    .payload(payload)
                    .timeout(Duration::from_secs(5))
                    .await
                    .ok()?;
                let reply = replies.recv_async().await.ok()?;
                Some(match reply.result() {
                    Ok(sample) => sample.payload().to_bytes().to_vec(),
                    Err(e) => e.payload().to_bytes().to_vec(),
                })
            }
        };
        for (user, field, request) in &api {
            let key = keys.api(&operator, request.call(), &st(user));
            for _ in 0..CASES {
                let bytes = random_bytes(&mut rng);
                let answer = ask(&sessions[user], key.clone(), spliced(request, &bytes)).await;
                check(field, &bytes, answer, false);
            }
        }
        for (caller, target, field, request) in &services {
            let key = keys.service(&st(target), request.service());
            for _ in 0..CASES {
                let bytes = random_bytes(&mut rng);
                let answer = ask(&sessions[caller], key.clone(), spliced(request, &bytes)).await;
                check(field, &bytes, answer, true);
            }
        }
        for (_, bus) in sessions {
            let _ = bus.session().close().await;
        }
    });
    println!("{sent} requests with random fields: every one answered, {accepted} accepted, the largest answer {largest} bytes");
    // Whatever was stored comes out escaped.
    let (code, journal) = rig.cell.falc_as("observer", &["journal"]);
    assert_eq!(code, 0, "{journal}");
    assert!(
        !journal.contains('\u{1b}') && !journal.contains('\u{7}'),
        "a raw escape in `falc journal`"
    );
    let (code, messages) = rig.cell.falc_as("observer", &["messages"]);
    assert_eq!(code, 0, "{messages}");
    assert!(!messages.contains('\u{1b}') && !messages.contains('\u{7}'));
    // Every node still runs, and an order runs to done.
    rig.next_order_done("dikdroog");
}
