//! Domain and program-invocation services end to end through the router:
//! the commander downloads a recipe in segments, creates the program
//! invocation, starts it, and sees the status change; refusals carry the
//! current state.

use crate::support::{st, TestCell};
use falc_bus::DEFAULT_DEADLINE;
use falc_model::ids::ObjectName;
use falc_model::mms::domain::DomainState;
use falc_model::mms::error::ServiceSpecific;
use falc_model::mms::pdu::{Request, Response};
use falc_model::mms::program::PiState;
use falc_model::mms::vmd::RecipeState;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn download_create_start_and_status() {
    let cell = TestCell::start();
    let _w = cell.demo_station("welding");
    let bus = cell.bus("cell").await.expect("session");
    let welding = st("welding");
    let call = |r: Request| {
        let bus = &bus;
        let welding = &welding;
        async move { bus.request(welding, &r, DEFAULT_DEADLINE).await }
    };
    let name = ObjectName::new("droog_dik").expect("valid");
    // Before Initiate, state-changing services are refused.
    let r = call(Request::InitiateDownloadSequence {
        domain: name.clone(),
    })
    .await;
    assert!(
        matches!(&r, Err(e) if e.description.contains("no associated commander")),
        "{r:?}"
    );
    let r = call(Request::Initiate {
        calling: bus.me().clone(),
    })
    .await;
    assert!(matches!(r, Ok(Response::Initiate { .. })), "{r:?}");

    let text = "#DROOG_DIK\n-1 | start rcm 65 | | gestart | 2\n".repeat(40);
    assert_eq!(
        call(Request::InitiateDownloadSequence {
            domain: name.clone()
        })
        .await,
        Ok(Response::Done)
    );
    let chunks: Vec<&[u8]> = text.as_bytes().chunks(500).collect();
    for (i, c) in chunks.iter().enumerate() {
        let r = call(Request::DownloadSegment {
            domain: name.clone(),
            data: c.to_vec(),
            more_follows: i + 1 < chunks.len(),
        })
        .await;
        assert_eq!(r, Ok(Response::Done));
    }
    assert_eq!(
        call(Request::TerminateDownloadSequence {
            domain: name.clone(),
            discard: None
        })
        .await,
        Ok(Response::Done)
    );
    match call(Request::GetDomainAttributes {
        domain: name.clone(),
    })
    .await
    {
        Ok(Response::DomainAttributes(a)) => {
            assert_eq!(a.state, DomainState::Ready);
            assert_eq!(a.size, text.len() as u64);
            assert_eq!(
                a.content_hash,
                falc_model::mms::domain::content_hash(text.as_bytes())
            );
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        call(Request::CreateProgramInvocation {
            name: name.clone(),
            domains: vec![name.clone()],
            reusable: true
        })
        .await,
        Ok(Response::Done)
    );
    let r = call(Request::Start {
        name: name.clone(),
        argument: String::new(),
    })
    .await;
    assert_eq!(r, Ok(Response::ProgramInvocationState(PiState::Starting)));
    match call(Request::Status).await {
        // It runs: its `start rcm 65` waits for the robot's confirm
        // (WAIT_ACK), or, confirmed, goes on.
        Ok(Response::Status(s)) => assert!(
            matches!(
                s.local_detail,
                RecipeState::WaitAck | RecipeState::Pending | RecipeState::Executing
            ),
            "{s:?}"
        ),
        other => panic!("{other:?}"),
    }
    // A second Start is refused with the current state.
    match call(Request::Start {
        name: name.clone(),
        argument: String::new(),
    })
    .await
    {
        Err(e) => assert_eq!(
            e.specific,
            Some(ServiceSpecific::ProgramInvocationState(PiState::Running))
        ),
        Ok(r) => panic!("second start accepted: {r:?}"),
    }
    // Upload returns the same text.
    let Ok(Response::UploadStarted { ulsm, size }) = call(Request::InitiateUploadSequence {
        domain: name.clone(),
    })
    .await
    else {
        panic!("upload refused")
    };
    assert_eq!(size, text.len() as u64);
    let mut back = Vec::new();
    loop {
        match call(Request::UploadSegment { ulsm }).await {
            Ok(Response::Segment { data, more_follows }) => {
                back.extend(data);
                if !more_follows {
                    break;
                }
            }
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(back, text.as_bytes());
    assert_eq!(
        call(Request::TerminateUploadSequence { ulsm }).await,
        Ok(Response::Done)
    );
}
