//! `osap describe RUNTIME FUNCTION`: what a PIPES function says of itself,
//! read from it: its signature, its documentation and its refusal codes
//! with their fixes (`osap_host::som::Description`).

use crate::network::signature_line;
use crate::Connect;
use osap_host::som::{Description, FnRef};
use std::fmt::Write as _;
use std::process::ExitCode;

/// `osap describe`'s arguments.
#[derive(clap::Args)]
pub(crate) struct DescribeArgs {
    #[command(flatten)]
    connect: Connect,
    /// The runtime's name (`osap scan` lists them).
    runtime: String,
    /// The function's name (`osap scan -f` lists every runtime's).
    function: String,
}

/// Reads the function's description (one request, after the scan) and
/// prints it.
pub(crate) async fn describe(args: DescribeArgs) -> Result<ExitCode, String> {
    let (c, manager) = crate::connection::connect_scanned(&args.connect).await?;
    let fref = FnRef::new(args.runtime.as_str(), args.function.as_str());
    let (_, function) = manager
        .som()
        .runtime_index(&fref.runtime)
        .ok()
        .and_then(|ri| Some((ri, manager.som().function(ri, &fref.function)?)))
        .ok_or_else(|| {
            format!(
                "no function {}.{} (`osap scan -f` lists every runtime's functions)",
                fref.runtime, fref.function
            )
        })?;
    let line = format!("{}.{}", fref.runtime, signature_line(function));
    let handle = manager
        .function(&fref)
        .map_err(|e| e.to_string())?
        .with_timeout(c.timeout);
    let d = handle.describe().await.map_err(|e| e.to_string())?;
    print!("{}", render(&line, &d));
    Ok(ExitCode::SUCCESS)
}

/// The description as printed: the signature, the documentation, then
/// one line per refusal code, `Name (code N): reason`.
fn render(signature: &str, d: &Description) -> String {
    let mut out = format!("{signature}\n\n");
    if d.docs.is_empty() {
        out.push_str("(no documentation: the function publishes none)\n");
    } else {
        out.push_str(&d.docs);
        out.push('\n');
    }
    out.push('\n');
    match &d.failures {
        None => out.push_str(
            "refusal codes: not published (a function from before the failure tables: \
             its device's own documentation names them)\n",
        ),
        Some(t) if t.is_empty() => out.push_str("refusal codes: none\n"),
        Some(t) => {
            out.push_str("refusal codes:\n");
            for f in t.iter() {
                let _ = writeln!(out, "  {f}");
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use osap_host::som::failure::Failure;

    #[test]
    fn a_description_prints_docs_and_every_code_by_name() {
        let d = Description {
            summary: "Feeds.".into(),
            docs: "Feeds.\nOne part.".into(),
            failures: Some(
                vec![Failure {
                    code: 5,
                    name: "Jammed".into(),
                    reason: "clear it".into(),
                }]
                .into(),
            ),
        };
        assert_eq!(
            render("b.feed()", &d),
            "b.feed()\n\nFeeds.\nOne part.\n\nrefusal codes:\n  Jammed (code 5): clear it\n"
        );
        let old = render("b.old()", &Description::default());
        assert!(old.contains("(no documentation"), "{old}");
        assert!(old.contains("refusal codes: not published"), "{old}");
    }
}
