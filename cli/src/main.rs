//! `bass`: the command-line tool of the bass broker. The command line and the commands live in
//! the [`bass_cli`] library; see docs/broker.md.
#![forbid(unsafe_code)]

fn main() {
    bass_cli::bass::main()
}
