//! docs/manifest.md documents every manifest key, and its "Component kinds" section is exactly
//! what the kind table generates (so a kind or parameter added to the build cannot go
//! undocumented). `UPDATE_DOCS=1` rewrites the generated section.

use conductor_devices::kinds::KINDS;
use conductor_manifest::reference::kinds_markdown;
use conductor_manifest::{
    BRIDGE_KEYS, DEVICE_KEYS, GATEWAY_KEYS, HARDWARE_KEYS, PROTOCOL_KEYS, STATE_KEYS,
    SUBSYSTEM_KEYS, TOP_KEYS, VIEW_KEYS,
};

const BEGIN: &str = "<!-- kinds:begin -->\n";
const END: &str = "<!-- kinds:end -->";

fn doc_path() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/manifest.md")
}

#[test]
fn the_kinds_section_is_generated_from_the_kind_table() {
    let doc = std::fs::read_to_string(doc_path()).unwrap();
    let start = doc.find(BEGIN).expect("begin marker") + BEGIN.len();
    let end = doc.find(END).expect("end marker");
    let generated = kinds_markdown(KINDS);
    if std::env::var_os("UPDATE_DOCS").is_some() {
        let new = format!("{}{generated}{}", &doc[..start], &doc[end..]);
        std::fs::write(doc_path(), new).unwrap();
        return;
    }
    assert!(
        doc[start..end] == generated,
        "docs/manifest.md's kinds section is out of date; run \
         `UPDATE_DOCS=1 cargo test -p conductor-manifest --test docs`"
    );
    // And it really lists them all.
    for k in KINDS {
        assert!(doc.contains(&format!("#### `{}`", k.kind)), "{}", k.kind);
        for p in k.params {
            assert!(
                doc.contains(&format!("| `{}` |", p.name)),
                "{}.{}",
                k.kind,
                p.name
            );
        }
    }
}

#[test]
fn every_manifest_key_is_documented() {
    let doc = std::fs::read_to_string(doc_path()).unwrap();
    for key in TOP_KEYS
        .iter()
        .chain(SUBSYSTEM_KEYS)
        .chain(HARDWARE_KEYS)
        .chain(PROTOCOL_KEYS)
        .chain(DEVICE_KEYS)
        .chain(STATE_KEYS)
        .chain(GATEWAY_KEYS)
        .chain(VIEW_KEYS)
        .chain(BRIDGE_KEYS)
    {
        let documented =
            doc.contains(&format!("| `{key}` |")) || doc.contains(&format!("`{key}`, "));
        assert!(
            documented,
            "manifest key `{key}` has no row in docs/manifest.md"
        );
    }
}
