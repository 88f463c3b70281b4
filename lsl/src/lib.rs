//! liblsl (the Lab Streaming Layer library), loaded at run time: bass never builds or ships it.
//! [`Lsl::load`] finds it where the user has it — a path given, `$PYLSL_LIB` (pylsl's own
//! variable), the system's `liblsl.so`, or the copy PyPI `pylsl` ships, found through python3 —
//! and resolves the few C functions an outlet needs. [`Outlet`] is one LSL stream outlet.
//!
//! liblsl's `lsl_local_clock()` is `std::chrono::steady_clock`, which on Linux reads
//! CLOCK_MONOTONIC: [`Lsl::clock_offset_s`] measures the difference to bass's CLOCK_MONOTONIC
//! stamps (0 within a microsecond on Linux) so that a caller converts exactly anyway.

#![deny(unsafe_code)]

use std::ffi::{c_char, c_void, CString};
use std::path::{Path, PathBuf};

#[allow(unsafe_code)] // the C API of liblsl, resolved with dlopen/dlsym
mod api;

pub use api::ChannelFormat;

/// A loaded liblsl.
pub struct Lsl {
    api: api::Api,
    /// Where it was found.
    pub path: PathBuf,
}

/// Where liblsl is looked for, in order: `explicit`, `$PYLSL_LIB`, the system's `liblsl.so`
/// (and `liblsl.so.2`), then pylsl's bundled copy (asking python3 where pylsl is).
fn candidates(explicit: Option<&Path>) -> Vec<PathBuf> {
    if let Some(p) = explicit {
        return vec![p.to_owned()];
    }
    let mut c = Vec::new();
    if let Some(p) = std::env::var_os("PYLSL_LIB") {
        c.push(PathBuf::from(p));
    }
    c.push("liblsl.so".into());
    c.push("liblsl.so.2".into());
    let py = std::process::Command::new("python3")
        .args([
            "-c",
            "import os, pylsl; print(os.path.join(os.path.dirname(pylsl.__file__), 'lib', 'liblsl.so'))",
        ])
        .stderr(std::process::Stdio::null())
        .output();
    if let Ok(o) = py {
        if o.status.success() {
            let p = String::from_utf8_lossy(&o.stdout).trim().to_owned();
            if !p.is_empty() {
                c.push(p.into());
            }
        }
    }
    c
}

impl Lsl {
    /// Loads liblsl (see [`candidates`] for where it is looked for); the error names every
    /// place tried and what to install.
    pub fn load(explicit: Option<&Path>) -> Result<Lsl, String> {
        let mut tried = Vec::new();
        for path in candidates(explicit) {
            match api::Api::load(&path) {
                Ok(api) => return Ok(Lsl { api, path }),
                Err(e) => tried.push(format!("{}: {e}", path.display())),
            }
        }
        Err(format!(
            "liblsl not found (tried {}): install it (`pip install pylsl`, whose wheel ships it, or \
             your distribution's liblsl), or give its path with --liblsl",
            tried.join("; ")
        ))
    }

    /// liblsl's version (e.g. 116 for 1.16).
    pub fn version(&self) -> i32 {
        self.api.library_version()
    }

    /// liblsl's clock (`lsl_local_clock`, seconds).
    pub fn local_clock(&self) -> f64 {
        self.api.local_clock()
    }

    /// LSL's clock minus `mono_s` (CLOCK_MONOTONIC now, read by the caller just before and
    /// after): the offset to add to a CLOCK_MONOTONIC stamp to get LSL's; the median of a few
    /// readings, each bracketed by two monotonic reads.
    pub fn clock_offset_s(&self, monotonic_s: impl Fn() -> f64) -> f64 {
        let mut d: Vec<f64> = (0..9)
            .map(|_| {
                let a = monotonic_s();
                let l = self.local_clock();
                let b = monotonic_s();
                l - (a + b) / 2.0
            })
            .collect();
        d.sort_by(|a, b| a.total_cmp(b));
        d[d.len() / 2]
    }

    /// A stream outlet: `name`, `kind` (LSL's content type, e.g. "Audio"), `channels`,
    /// `rate` (0: irregular), `format`, `source_id`; `desc` adds `(path, value)` elements to the
    /// stream's description (`path` like "bass/broker" creates the parents as needed, in order;
    /// a part `name#key` is an element `name`, the key only telling siblings apart, as in
    /// "channels/channel#0/label").
    pub fn outlet(&self, s: &StreamSpec<'_>) -> Result<Outlet<'_>, String> {
        let c = |v: &str, what: &str| CString::new(v).map_err(|_| format!("{what} {v:?} contains a NUL"));
        let info = self.api.create_streaminfo(
            &c(s.name, "stream name")?,
            &c(s.kind, "stream type")?,
            s.channels,
            s.rate,
            s.format,
            &c(s.source_id, "source id")?,
        );
        if info.is_null() {
            return Err(format!("liblsl refused the stream {:?}", s.name));
        }
        let desc = self.api.get_desc(info);
        let mut made: Vec<(String, *mut c_void)> = Vec::new();
        for (path, value) in s.desc {
            let (parent_path, leaf) = path.rsplit_once('/').unwrap_or(("", path));
            let mut parent = desc;
            let mut so_far = String::new();
            for part in parent_path.split('/').filter(|p| !p.is_empty()) {
                so_far = if so_far.is_empty() { part.to_owned() } else { format!("{so_far}/{part}") };
                parent = match made.iter().find(|(p, _)| *p == so_far) {
                    Some((_, e)) => *e,
                    None => {
                        let e = self.api.append_child(parent, &c(element_name(part), "element")?);
                        made.push((so_far.clone(), e));
                        e
                    }
                };
            }
            self.api.append_child_value(parent, &c(element_name(leaf), "element")?, &c(value, "value")?);
        }
        let outlet = self.api.create_outlet(info, 0, 360);
        self.api.destroy_streaminfo(info);
        if outlet.is_null() {
            return Err(format!("liblsl could not make the outlet {:?}", s.name));
        }
        Ok(Outlet { lsl: self, outlet, channels: s.channels as usize })
    }
}

/// What an outlet publishes.
pub struct StreamSpec<'a> {
    /// Stream name.
    pub name: &'a str,
    /// Content type ("Audio", "Markers").
    pub kind: &'a str,
    /// Channels.
    pub channels: i32,
    /// Nominal rate in Hz (0: irregular).
    pub rate: f64,
    /// Sample format.
    pub format: ChannelFormat,
    /// A stable identifier of the source (recovers an inlet across outlet restarts).
    pub source_id: &'a str,
    /// Description elements: ("parent/child", value).
    pub desc: &'a [(String, String)],
}

/// One LSL stream outlet (closed when dropped).
pub struct Outlet<'a> {
    lsl: &'a Lsl,
    outlet: *mut c_void,
    channels: usize,
}

impl Outlet<'_> {
    /// Pushes `samples` (interleaved int32, a whole number of samples), each with its own
    /// timestamp (LSL's clock, seconds).
    pub fn push_i32(&self, samples: &[i32], timestamps: &[f64]) -> Result<(), String> {
        if samples.len() != timestamps.len() * self.channels {
            return Err(format!(
                "{} values for {} timestamps of {} channels",
                samples.len(),
                timestamps.len(),
                self.channels
            ));
        }
        match self.lsl.api.push_chunk_itnp(self.outlet, samples, timestamps) {
            0 => Ok(()),
            e => Err(format!("lsl_push_chunk_itnp failed ({e})")),
        }
    }

    /// Pushes one string sample (a 1-channel string stream) stamped `timestamp`.
    pub fn push_str(&self, text: &str, timestamp: f64) -> Result<(), String> {
        let c = CString::new(text).map_err(|_| "a marker with a NUL".to_owned())?;
        let p: [*const c_char; 1] = [c.as_ptr()];
        match self.lsl.api.push_sample_strtp(self.outlet, &p, timestamp) {
            0 => Ok(()),
            e => Err(format!("lsl_push_sample_strtp failed ({e})")),
        }
    }

    /// Whether an inlet is connected.
    pub fn has_consumers(&self) -> bool {
        self.lsl.api.have_consumers(self.outlet) != 0
    }
}

impl Drop for Outlet<'_> {
    fn drop(&mut self) {
        self.lsl.api.destroy_outlet(self.outlet);
    }
}

/// The element name of a description path part (`channel#3` → `channel`).
fn element_name(part: &str) -> &str {
    part.split_once('#').map_or(part, |(name, _)| name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_liblsl_is_refused_naming_the_place_and_what_to_install() {
        let e = Lsl::load(Some(Path::new("/nonexistent/liblsl.so"))).err().expect("no such library");
        assert!(
            e.contains("/nonexistent/liblsl.so") && e.contains("pip install pylsl") && e.contains("--liblsl"),
            "{e}"
        );
    }

    #[test]
    fn a_library_that_is_not_liblsl_is_refused_by_the_function_it_lacks() {
        // libc is loaded in every process and has none of liblsl's functions.
        let e = Lsl::load(Some(Path::new("libc.so.6"))).err().expect("not liblsl");
        assert!(e.contains("not liblsl (lsl_create_streaminfo"), "{e}");
    }
}
