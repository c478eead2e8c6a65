//! The bad-manifest corpus: every file in `tests/bad_manifests/` is rejected with exactly the
//! diagnostics (file, line, column, key, message) in its `.expected` snapshot.
//!
//! After an intended change of wording, regenerate the snapshots with
//! `UPDATE_SNAPSHOTS=1 cargo test -p conductor-manifest --test bad_manifests` and review the diff.

use std::path::Path;

use conductor_devices::kinds::{
    Build, BuildError, Capacity, HardwareBuild, KindSpec, OpenedHardware, ParamSpec, Params, Role,
    KINDS,
};
use conductor_manifest::{Manifest, ManifestError};

/// A serial-like hardware whose `port` is an exclusive OS resource, so the corpus can show the
/// "two subsystems on one serial device" error whatever real kinds this build has.
const TEST_SERIAL: KindSpec = KindSpec {
    kind: "test-serial",
    params: &[ParamSpec::text("port", None, "device path")],
    doc: "test-only serial hardware",
    build: Build::Hardware {
        resource: Some("port"),
        open: HardwareBuild::Bytes(never_opened),
    },
};

/// The corpus is only validated: nothing opens [`TEST_SERIAL`].
fn never_opened(_: &Params, _: Capacity) -> Result<OpenedHardware<u8>, BuildError> {
    Err(BuildError::UnknownKind {
        role: Role::Hardware,
        kind: "test-serial".into(),
    })
}

/// The built-in simulated kinds plus [`TEST_SERIAL`]: a fixed table, so that the snapshots (which
/// list the known kinds in some messages) do not change when real kinds are added to the build.
/// The bus-load files (`NN-bus-load-*.toml`) need real buses: they get every kind.
fn kinds(file: &str) -> Vec<KindSpec> {
    if file.contains("-bus-load-") {
        return KINDS.to_vec();
    }
    let mut k: Vec<KindSpec> = KINDS
        .iter()
        .filter(|k| matches!(k.kind, "sine" | "loopback" | "sim"))
        .copied()
        .collect();
    k.push(TEST_SERIAL);
    k
}

fn diagnostics(path: &Path) -> String {
    let source = std::fs::read_to_string(path).unwrap();
    let name = path.file_name().unwrap().to_str().unwrap();
    match Manifest::parse_with_kinds(&source, name, &kinds(name)) {
        Ok(_) => panic!("{name} was accepted"),
        Err(ManifestError::Invalid { diagnostics }) => {
            assert!(!diagnostics.is_empty());
            let mut out = String::new();
            for d in &diagnostics {
                assert_eq!(d.file, name);
                assert!(d.line >= 1 && d.column >= 1);
                // The reported position is inside the file.
                let lines: Vec<&str> = source.lines().collect();
                assert!(d.line <= lines.len().max(1), "{d}");
                out.push_str(&d.to_string());
                out.push('\n');
            }
            out
        }
        Err(e) => panic!("{name}: unexpected error {e}"),
    }
}

#[test]
fn every_bad_manifest_is_rejected_as_expected() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad_manifests");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 15, "the corpus has {} files", files.len());
    let update = std::env::var_os("UPDATE_SNAPSHOTS").is_some();
    let mut failures = Vec::new();
    for f in &files {
        let got = diagnostics(f);
        let snap = f.with_extension("expected");
        if update {
            std::fs::write(&snap, &got).unwrap();
            continue;
        }
        let want = std::fs::read_to_string(&snap)
            .unwrap_or_else(|_| panic!("missing snapshot {}", snap.display()));
        if got != want {
            failures.push(format!(
                "{}:\n--- expected\n{want}--- got\n{got}",
                f.display()
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The rendered error of `Manifest::load` names the file and counts the errors.
#[test]
fn load_renders_every_diagnostic() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad_manifests/04-dangling-links.toml");
    let e = Manifest::load(&path).unwrap_err();
    let text = e.to_string();
    assert_eq!(text.lines().count(), 4, "{text}");
    assert!(text.ends_with("3 errors in the manifest"), "{text}");
    assert!(text.starts_with(&path.display().to_string()), "{text}");
}

#[test]
fn missing_file_is_an_io_error() {
    let e = Manifest::load("/nonexistent/robot.toml").unwrap_err();
    assert!(matches!(e, ManifestError::Io { .. }));
    assert!(e.to_string().contains("/nonexistent/robot.toml"));
}
