//! Independent readers for skelslice outputs (a test tool, not part of the package).
//!
//! ```text
//! skelslice-readers cli FILE   # binary CLI, parsed by the `colain` crate
//! skelslice-readers goo FILE   # Elegoo GOO, parsed by the `goo` crate
//! skelslice-readers nanodlp FILE  # NanoDLP zip, parsed by `msla_format` (GPL-3.0)
//! ```
//!
//! Each subcommand prints one JSON object on stdout and exits 0, or prints
//! `{"error": "..."}` and exits 1 when the third-party parser rejects the
//! file (or panics on it: `colain` and `goo` index without bounds checks of
//! their own, and `msla_format`'s NanoDLP layer decoder unwraps the PNG
//! decode, so a truncated file panics; the panic is caught and reported).

mod cli;
mod goo_check;
mod json;
mod nanodlp_check;

use std::process::ExitCode;

fn usage() -> ExitCode {
    eprintln!("usage: skelslice-readers (cli|goo|nanodlp) FILE");
    ExitCode::from(2)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 3 {
        return usage();
    }
    let data = match std::fs::read(&args[2]) {
        Ok(d) => d,
        Err(e) => {
            println!("{}", json::error(&format!("{}: {}", args[2], e)));
            return ExitCode::from(1);
        }
    };
    // The parsers panic on truncated input; report that as a rejection.
    std::panic::set_hook(Box::new(|_| {}));
    let which = args[1].clone();
    let result = std::panic::catch_unwind(move || match which.as_str() {
        "cli" => Some(cli::report(&data)),
        "goo" => Some(goo_check::report(&data)),
        "nanodlp" => Some(nanodlp_check::report(&data)),
        _ => None,
    });
    match result {
        Ok(Some(Ok(text))) => {
            println!("{}", text);
            ExitCode::SUCCESS
        }
        Ok(Some(Err(msg))) => {
            println!("{}", json::error(&msg));
            ExitCode::from(1)
        }
        Ok(None) => usage(),
        Err(_) => {
            println!("{}", json::error("the parser panicked (truncated or corrupt file)"));
            ExitCode::from(1)
        }
    }
}
