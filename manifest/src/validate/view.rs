//! The `[view]` table: the live view in Foxglove (`conductor view`), run by the launcher.

use super::super::reader::Table;
use super::super::{ViewDef, VIEW_KEYS};
use super::Ctx;

/// Validates the view table; `None` if anything in it is wrong (errors recorded).
pub(super) fn view(cx: &mut Ctx, t: &mut Table) -> Option<ViewDef> {
    let default = ViewDef::default();
    let listen = match t.str(&mut cx.d, "listen") {
        None if t.span_of("listen").is_some() => None,
        None => Some(default.listen),
        Some(l) => match l.value.parse() {
            Ok(a) => Some(a),
            Err(_) => {
                cx.d.error(
                    &l.span,
                    &t.key_path("listen"),
                    format!(
                        "expected an address and port such as \"127.0.0.1:8765\" (loopback) or \
                         \"0.0.0.0:8765\" (every interface), found {:?}",
                        l.value
                    ),
                );
                None
            }
        },
    };
    let clamp = t.bool(&mut cx.d, "clamp");
    t.finish(&mut cx.d, VIEW_KEYS);
    let clamp = match (clamp, t.span_of("clamp")) {
        (Some(c), _) => c.value,
        (None, Some(_)) => return None,
        (None, None) => default.clamp,
    };
    Some(ViewDef {
        listen: listen?,
        clamp,
    })
}

#[cfg(test)]
mod tests {
    use crate::{Manifest, ManifestError, ViewDef};

    const ROBOT: &str = include_str!("../../../executors/tests/manifests/two-subsystems.toml");

    fn parse(view: &str) -> Result<Manifest, ManifestError> {
        Manifest::parse(&format!("{ROBOT}\n{view}"), "robot.toml")
    }

    #[test]
    fn a_view_table_runs_the_view() {
        assert_eq!(parse("").unwrap().view, None);
        assert_eq!(parse("[view]").unwrap().view, Some(ViewDef::default()));
        let v = parse("[view]\nlisten = \"0.0.0.0:9000\"\nclamp = true")
            .unwrap()
            .view
            .unwrap();
        assert_eq!(v.listen.to_string(), "0.0.0.0:9000");
        assert!(v.clamp);
    }

    #[test]
    fn a_bad_view_table_says_what_was_expected() {
        let e = parse("[view]\nlisten = \"localhost\"")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("view.listen: expected an address and port such as \"127.0.0.1:8765\""),
            "{e}"
        );
        let e = parse("[view]\nclamp = 1\nport = 3")
            .unwrap_err()
            .to_string();
        assert!(e.contains("view.clamp"), "{e}");
        assert!(e.contains("view.port"), "{e}");
        let e = parse("view = 3").unwrap_err().to_string();
        assert!(e.contains("view"), "{e}");
    }
}
