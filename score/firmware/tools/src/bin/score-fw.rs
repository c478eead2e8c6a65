//! `score-fw`: build the Score firmware and report its size, convert it to UF2, run it in the
//! emulator.
//!
//! ```text
//! score-fw build              cargo build --release --locked in score/firmware, then UF2 + size
//! score-fw uf2 <elf> [<uf2>]  write the UF2 (default: beside the ELF)
//! score-fw size <elf>         flash and RAM use
//! score-fw emulate            run the firmware in rp2040js; prints the two PTY paths, Ctrl-C ends
//! ```

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use score_firmware_tools::{emulator::Emulator, image, paths};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let r = match args
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>()
        .as_slice()
    {
        ["build"] => build(),
        ["uf2", elf] => uf2(Path::new(elf), None),
        ["uf2", elf, out] => uf2(Path::new(elf), Some(Path::new(out))),
        ["size", elf] => size(Path::new(elf)),
        ["emulate"] => emulate(),
        _ => Err("usage: score-fw build | uf2 <elf> [<uf2>] | size <elf> | emulate".into()),
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("score-fw: {e}");
            ExitCode::FAILURE
        }
    }
}

fn read(p: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))
}

fn build() -> Result<(), String> {
    let dir = paths::firmware_dir();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let status = Command::new(cargo)
        .current_dir(&dir)
        .args(["build", "--release", "--locked"])
        // The workspace's target dir or flags must not leak into the firmware's own build.
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("RUSTFLAGS")
        .status()
        .map_err(|e| format!("cannot run cargo: {e}"))?;
    if !status.success() {
        return Err(format!("firmware build failed ({status})"));
    }
    let elf = paths::default_elf();
    uf2(&elf, None)?;
    size(&elf)
}

fn uf2(elf: &Path, out: Option<&Path>) -> Result<(), String> {
    let img = image::uf2(&read(elf)?).map_err(|e| e.to_string())?;
    let out: PathBuf = out.map_or_else(|| elf.with_extension("uf2"), Path::to_path_buf);
    std::fs::write(&out, &img).map_err(|e| format!("{}: {e}", out.display()))?;
    println!("wrote {} ({} blocks)", out.display(), img.len() / 512);
    Ok(())
}

fn size(elf: &Path) -> Result<(), String> {
    let u = image::usage(&read(elf)?).map_err(|e| e.to_string())?;
    println!("{}: {u}", elf.display());
    Ok(())
}

fn emulate() -> Result<(), String> {
    let emu = Emulator::start().map_err(|e| e.to_string())?;
    println!("terminal: {}", emu.term.display());
    println!("link:     {}", emu.link.display());
    println!(
        "(score-gateway --port {}; Ctrl-C to stop)",
        emu.link.display()
    );
    loop {
        std::thread::park();
    }
}
