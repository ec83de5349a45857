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
/// `[2][parts]` is malformed, everything else as usual, and a call fails
/// with code 5.
async fn serve_old_function(port: osap_host::PortHandle) {
    loop {
        let d = port.recv().await;
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
    let server = tokio::spawn(serve_old_function(old));
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
