//! `bass`: the command-line tool of the bass broker. The command line and the commands live in
//! the [`bass_cli`] library; see docs/broker.md.

fn main() {
    bass_cli::bass::main()
}
