//! A minimal command-line parser shared by `bassd` and `bass`: `--key value` options,
//! `--flag` switches and positional words.

use std::collections::HashMap;
use std::str::FromStr;

use anyhow::{anyhow, bail, Result};

/// Parsed arguments.
#[derive(Debug, Default)]
pub struct Args {
    opts: HashMap<String, String>,
    flags: Vec<String>,
    /// Positional words, in order.
    pub words: Vec<String>,
}

impl Args {
    /// Parses `args` (without the program name); `valued` lists the options that take a value,
    /// `switches` the ones that do not. Anything else starting with `--` is an error.
    pub fn parse(args: impl IntoIterator<Item = String>, valued: &[&str], switches: &[&str]) -> Result<Args> {
        let mut a = Args::default();
        let mut it = args.into_iter();
        while let Some(w) = it.next() {
            if let Some(opt) = w.strip_prefix("--") {
                let (k, inline) = match opt.split_once('=') {
                    Some((k, v)) => (k, Some(v.to_owned())),
                    None => (opt, None),
                };
                if valued.contains(&k) {
                    let v = match inline {
                        Some(v) => v,
                        None => it.next().ok_or_else(|| anyhow!("option --{k} needs a value"))?,
                    };
                    a.opts.insert(k.to_owned(), v);
                } else if switches.contains(&k) && inline.is_none() {
                    a.flags.push(k.to_owned());
                } else {
                    bail!("unknown option --{k} (try --help)");
                }
            } else {
                a.words.push(w);
            }
        }
        Ok(a)
    }

    /// Value of `--key`, parsed, or `default`.
    pub fn get<T: FromStr>(&self, key: &str, default: T) -> Result<T> {
        match self.opts.get(key) {
            Some(v) => v.parse().map_err(|_| anyhow!("--{key} {v:?} is not valid")),
            None => Ok(default),
        }
    }

    /// Value of `--key` as text.
    pub fn text(&self, key: &str) -> Option<&str> {
        self.opts.get(key).map(String::as_str)
    }

    /// Whether `--flag` was given.
    pub fn flag(&self, key: &str) -> bool {
        self.flags.iter().any(|f| f == key)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_switches_and_words() {
        let v = |s: &str| s.split(' ').map(String::from).collect::<Vec<_>>();
        let a = Args::parse(
            v("acquire sim:sine --rate 48000 --frames=64 --wait"),
            &["rate", "frames"],
            &["wait"],
        )
        .unwrap();
        assert_eq!(a.words, ["acquire", "sim:sine"]);
        assert_eq!(a.get("rate", 0u32).unwrap(), 48000);
        assert_eq!(a.get("frames", 0u32).unwrap(), 64);
        assert_eq!(a.get("chunks", 20u32).unwrap(), 20);
        assert!(a.flag("wait"));
        assert!(Args::parse(v("--bogus"), &[], &[]).is_err());
        assert!(Args::parse(v("--rate"), &["rate"], &[]).is_err());
    }
}
