//! The "component kinds" section of the manifest reference (`docs/manifest.md`), generated from
//! the kind table so that the documentation lists exactly what the build accepts.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use conductor_devices::kinds::{self, KindSpec, ParamDefault, ParamType, Params, Role};
use conductor_devices::Credential;

fn ty(t: ParamType) -> &'static str {
    match t {
        ParamType::Int => "integer",
        ParamType::Float => "number",
        ParamType::Bool => "boolean",
        ParamType::Str => "string",
    }
}

fn default_text(d: Option<ParamDefault>) -> String {
    match d {
        None => "required".into(),
        Some(ParamDefault::Int(v)) => v.to_string(),
        Some(ParamDefault::Float(v)) => format!("{v}"),
        Some(ParamDefault::Bool(v)) => v.to_string(),
        Some(ParamDefault::Str(v)) => format!("`{v:?}`"),
        Some(ParamDefault::Unset) => "unset (left as the device has it)".into(),
    }
}

fn role_title(r: Role) -> &'static str {
    match r {
        Role::Hardware => "Hardware kinds (`[subsystems.<s>.hardware.<name>]`)",
        Role::Protocol => "Protocol kinds (`[subsystems.<s>.protocols.<name>]`)",
        Role::Device => "Device kinds (`[subsystems.<s>.devices.<name>]`)",
    }
}

/// Markdown for every kind of `kinds`, grouped by stage: description, medium, exclusive resource,
/// the protocols a device sits on, its channels (when it can be built from defaults), and a table
/// of parameters (type, default, range or choices, meaning).
pub fn kinds_markdown(kinds: &[KindSpec]) -> String {
    let mut out = String::new();
    for role in [Role::Hardware, Role::Protocol, Role::Device] {
        let _ = writeln!(out, "### {}\n", role_title(role));
        for k in kinds.iter().filter(|k| k.role() == role) {
            let _ = writeln!(out, "#### `{}`\n\n{}\n", k.kind, k.doc);
            if let Some(m) = k.medium() {
                let _ = writeln!(out, "- Carries: {}.", m.name());
            }
            if let Some(r) = k.resource() {
                let _ = writeln!(
                    out,
                    "- Exclusive resource: `{r}` (no two hardware components of a manifest may \
                     name the same one)."
                );
            }
            if !k.protocols().is_empty() {
                let names: Vec<String> = k.protocols().iter().map(|p| format!("`{p}`")).collect();
                let _ = writeln!(out, "- Sits on protocols of kind: {}.", names.join(", "));
            }
            if role == Role::Device && k.params.iter().all(|p| p.default.is_some()) {
                let params = Params::new(k, BTreeMap::new());
                if let Ok(dev) = kinds::build_device(k.kind, &params, Credential::id(0)) {
                    let chans: Vec<String> = dev
                        .channels()
                        .iter()
                        .map(|c| {
                            let rw = match (c.readable, c.writable) {
                                (true, true) => "read/write",
                                (true, false) => "read-only",
                                (false, true) => "write-only",
                                (false, false) => "none",
                            };
                            let units = if c.units.is_empty() {
                                "unitless".to_string()
                            } else {
                                c.units.to_string()
                            };
                            format!("`{}` ({units}, {rw})", c.name)
                        })
                        .collect();
                    let _ = writeln!(out, "- Channels: {}.", chans.join(", "));
                }
            }
            if k.params.is_empty() {
                let _ = writeln!(out, "- No parameters.\n");
                continue;
            }
            let _ = writeln!(
                out,
                "\n| key | type | default | range / choices | meaning |\n|---|---|---|---|---|"
            );
            for p in k.params {
                let range = match (p.range, p.choices) {
                    (Some((lo, hi)), _) => format!("{lo} … {hi}"),
                    (None, c) if !c.is_empty() => c
                        .iter()
                        .map(|x| format!("`{x:?}`"))
                        .collect::<Vec<_>>()
                        .join(", "),
                    _ => "—".into(),
                };
                let _ = writeln!(
                    out,
                    "| `{}` | {} | {} | {} | {} |",
                    p.name,
                    ty(p.ty),
                    default_text(p.default),
                    range,
                    p.doc
                );
            }
            out.push('\n');
        }
    }
    out
}
