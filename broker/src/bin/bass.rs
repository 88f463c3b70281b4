//! `bass`: the command-line tool of the bass broker. The command line and the commands live in
//! the library's [`bassd::cli`] module tree; see docs/broker.md.

fn main() {
    bassd::cli::bass::main()
}
