//! Refusals by name from the function's own table: a scanned function that
//! publishes one has its codes named, whatever the device; one from before
//! the tables (which refuses `[2][parts]` as malformed) is still read, and
//! its codes print as numbers.

mod common;
use common::{host, refresh};

use osap_core::codec::Writer;
use osap_host::link::memory;
use osap_host::som::{attach_function, FnRef, HostFnError, HostFunction, Manager, SomError};
use pipes_core::control::{
    encode_signature_reply, ControlError, ControlKey, InputMode, OutputMode, Reply, ReplyBody,
    Request,
};
use pipes_core::failure::Failure;
use pipes_core::function::FUNCTION_PORT_TYPE;
use pipes_core::signature::Signature;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

static JAM: [Failure; 2] = [
    Failure {
        code: 5,
        name: "Jammed",
        reason: "the feeder is jammed: clear it, then call again",
    },
    Failure {
        code: 6,
        name: "Empty",
        reason: "",
    },
];

static OLD: Signature = Signature {
    name: "old",
    inputs: &[],
    outputs: &[],
};

/// A function port as a firmware from before the failure tables answers:
/// `[2][parts]` is malformed (counted in `refused`), everything else as
/// usual, and a call fails with code 5.
async fn serve_old_function(port: osap_host::PortHandle, refused: Arc<AtomicUsize>) {
    loop {
        let d = port.recv().await;
        if matches!(Request::parse(&d.body), Ok(Request::Describe(_))) {
            refused.fetch_add(1, Ordering::Relaxed);
        }
        let mut buf = [0u8; 64];
        let mut w = Writer::new(&mut buf);
        let reply = |key: ControlKey, result| Reply {
            key: key.to_u8(),
            result,
        };
        let r = match Request::parse(&d.body) {
            Ok(Request::GetSignature) => encode_signature_reply(&mut w, &OLD),
            Ok(Request::GetInputMode) => reply(
                ControlKey::GetInputMode,
                Ok(ReplyBody::InputMode(InputMode::OnAnyFresh)),
            )
            .encode(&mut w),
            Ok(Request::GetOutputMode) => reply(
                ControlKey::GetOutputMode,
                Ok(ReplyBody::OutputMode(OutputMode::Always)),
            )
            .encode(&mut w),
            Ok(Request::GetPipeCount) => reply(
                ControlKey::GetPipeCount,
                Ok(ReplyBody::PipeCount { slots: 0, used: 0 }),
            )
            .encode(&mut w),
            Ok(Request::Call(_)) => reply(
                ControlKey::Call,
                Err(ControlError::CallFailed(pipes_core::FailureCode::Other(5))),
            )
            .encode(&mut w),
            _ => Reply {
                key: d.body.first().copied().unwrap_or(0),
                result: Err(ControlError::Malformed),
            }
            .encode(&mut w),
        };
        r.unwrap();
        let n = w.len();
        port.reply(&d, &buf[..n]).await.unwrap();
    }
}

#[tokio::test]
async fn refusals_are_named_from_the_scanned_table_and_old_functions_still_read() {
    let (h, b) = (host("h"), host("b"));
    let feed = HostFunction::new("feed", &[], &[], |_| Err(HostFnError::new(5)))
        .unwrap()
        .with_failures(&JAM)
        .unwrap();
    attach_function(&b, feed).await.unwrap();
    let old = b.open_port(FUNCTION_PORT_TYPE).await.unwrap();
    let server = tokio::spawn(serve_old_function(old, Arc::default()));
    memory::connect(&h, &b).await.unwrap();
    let mut m = Manager::new(&h).await.unwrap();
    refresh(&mut m).await;

    let e = m
        .function(&FnRef::new("b", "feed"))
        .unwrap()
        .call(&[])
        .await
        .unwrap_err();
    let SomError::Remote {
        failure: Some(f), ..
    } = &e
    else {
        panic!("{e:?}")
    };
    assert_eq!((f.code, f.name.as_str()), (5, "Jammed"));
    assert!(
        e.to_string().ends_with(
            "call refused: Jammed (code 5): the feeder is jammed: clear it, then call again"
        ),
        "{e}"
    );

    // Same code, another function: no table, no name.
    let e = m
        .function(&FnRef::new("b", "old"))
        .unwrap()
        .call(&[])
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            SomError::Remote {
                error: ControlError::CallFailed(_),
                failure: None,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().ends_with("failed with code 5"), "{e}");
    server.abort();
}

#[test]
fn a_table_beyond_the_limits_is_refused() {
    static TWICE: [Failure; 2] = [
        Failure {
            code: 1,
            name: "A",
            reason: "",
        },
        Failure {
            code: 1,
            name: "B",
            reason: "",
        },
    ];
    let f = HostFunction::new("f", &[], &[], |_| Ok(vec![])).unwrap();
    let e = f.with_failures(&TWICE).err().unwrap();
    assert!(e.to_string().contains("code 1 twice"), "{e}");
}

const FEED_DOCS: &str = "Feeds one part.\nRefuses when jammed or empty.";

#[tokio::test]
async fn summaries_come_with_the_scan_and_docs_on_demand_and_old_functions_read_as_undocumented() {
    let (h, b) = (host("h"), host("b"));
    let feed = HostFunction::new("feed", &[], &[], |_| Err(HostFnError::new(5)))
        .unwrap()
        .with_failures(&JAM)
        .unwrap()
        .with_docs(FEED_DOCS)
        .unwrap();
    attach_function(&b, feed).await.unwrap();
    let refused = Arc::new(AtomicUsize::new(0));
    let mut servers = Vec::new();
    // More old functions than a runtime's functions read at once.
    const OLD_FUNCTIONS: usize = 8;
    for _ in 0..OLD_FUNCTIONS {
        let old = b.open_port(FUNCTION_PORT_TYPE).await.unwrap();
        servers.push(tokio::spawn(serve_old_function(old, refused.clone())));
    }
    memory::connect(&h, &b).await.unwrap();
    let mut m = Manager::new(&h).await.unwrap();
    refresh(&mut m).await;

    let rb = m.som().runtime_index("b").unwrap();
    let functions = &m.som().runtimes[rb].functions;
    let summary = |name: &str| {
        let f = functions.iter().find(|f| f.name == name).unwrap();
        f.summary.clone()
    };
    assert_eq!(summary("feed"), "Feeds one part.");
    assert_eq!(summary("old"), "");
    assert_eq!(
        functions.iter().filter(|f| f.name == "old").count(),
        OLD_FUNCTIONS
    );
    // A runtime's functions are read a link quota at a time: those asked
    // `[2][02]` before the first refusal came back refused it; the rest of
    // the runtime's functions were asked `[2]` alone.
    let refused = refused.load(Ordering::Relaxed);
    assert!(
        (1..=usize::from(osap_core::stack::DEFAULT_LINK_QUOTA)).contains(&refused),
        "{refused} of {OLD_FUNCTIONS} old functions refused the request with sections"
    );
    // In the model's JSON only where there is one.
    let json = m.som().to_json();
    assert_eq!(json.matches("\"summary\"").count(), 1, "{json}");

    let d = m.describe(&FnRef::new("b", "feed")).await.unwrap();
    assert_eq!(d.summary, "Feeds one part.");
    assert_eq!(d.docs, FEED_DOCS);
    let table = d.failures.unwrap();
    let lines: Vec<String> = table.iter().map(ToString::to_string).collect();
    assert_eq!(
        lines,
        [
            "Jammed (code 5): the feeder is jammed: clear it, then call again",
            "Empty (code 6)"
        ]
    );
    let d = m.describe(&FnRef::new("b", "old")).await.unwrap();
    assert_eq!(d, osap_host::som::Description::default());
    for s in servers {
        s.abort();
    }
}

#[test]
fn docs_beyond_the_limit_are_refused() {
    let f = HostFunction::new("f", &[], &[], |_| Ok(vec![])).unwrap();
    let long = "x".repeat(pipes_core::docs::MAX_DOCS + 1);
    let e = f.with_docs(&long).err().unwrap();
    assert!(e.to_string().contains("longer than 2048 bytes"), "{e}");
}
