//! The device policy: which device names a control client may make the broker open.
//!
//! ALSA's PCM names are a small language: besides card references (`hw:1,0`) they can
//! define plugins inline (`file:'|cmd',raw`, `{ type file file "/x" }`) that run commands
//! or write files as the broker's user. A client may therefore name only
//!
//! - card references: `hw`, `plughw`, `dsnoop`, `sysdefault` or `default`, alone or with
//!   plain arguments (`hw:1,0`, `plughw:CARD=PCH,DEV=0`, `default:U0x46d0x825`): letters,
//!   digits and `_ = , . -` only;
//! - simulated devices `sim:NAME`, except the file replay devices `sim:file:PATH`,
//!   `sim:file-renumber:PATH` and `sim:file-loop:PATH`;
//! - the PCM names the broker itself lists in ListDevices (hints of the system's ALSA
//!   configuration, which only the machine's administrator writes);
//! - whatever the operator allowed with `bassd --allow-device PATTERN` (glob syntax:
//!   `*` any text, `?` one character, `[abc]` a class; `[*]` a literal star). A name
//!   with a `/..` path step never matches a pattern.
//!
//! Everything else is refused before anything is touched, with the reason named.

use bassport::control::DeviceInfo;

/// Card-reference PCMs a client may always name (with plain arguments).
pub const CARD_PCMS: [&str; 5] = ["hw", "plughw", "dsnoop", "sysdefault", "default"];

/// The broker's device policy.
#[derive(Clone, Debug, Default)]
pub struct DevicePolicy {
    allow: Vec<glob::Pattern>,
}

impl DevicePolicy {
    /// A policy widened by the operator's `--allow-device` patterns.
    pub fn new(patterns: &[String]) -> Result<DevicePolicy, String> {
        let allow = patterns
            .iter()
            .map(|p| glob::Pattern::new(p).map_err(|e| format!("--allow-device {p:?}: {e}")))
            .collect::<Result<_, _>>()?;
        Ok(DevicePolicy { allow })
    }

    /// Whether a client may open `name`; `listed` gives the names ListDevices shows (only
    /// asked for when the cheaper rules did not decide).
    pub fn check(&self, name: &str, listed: impl FnOnce() -> Vec<DeviceInfo>) -> Result<(), String> {
        if let Some(sim) = name.strip_prefix("sim:") {
            // `sim:file:PATH`, `sim:file-renumber:PATH`, `sim:file-loop:PATH` read files: operator patterns only.
            if !sim.starts_with("file") {
                return Ok(());
            }
        } else if is_card_reference(name) {
            return Ok(());
        }
        if self.allowed_by_pattern(name) {
            return Ok(());
        }
        if !name.starts_with("sim:") && listed().iter().any(|d| d.name == name) {
            return Ok(());
        }
        Err(format!(
            "device {name:?} is not allowed by this broker's device policy ({}); clients may name \
             hw:/plughw:/dsnoop:/sysdefault:/default card references, sim: devices and the PCMs \
             `bass devices` lists; the operator can allow more with bassd --allow-device PATTERN",
            refusal_reason(name)
        ))
    }

    fn allowed_by_pattern(&self, name: &str) -> bool {
        if name.contains("/..") {
            return false;
        }
        self.allow.iter().any(|p| p.matches(name))
    }
}

/// `hw`, `hw:1,0`, `plughw:CARD=PCH,DEV=0` ...: a card PCM with plain arguments.
fn is_card_reference(name: &str) -> bool {
    let (base, args) = match name.split_once(':') {
        Some((_, "")) => return false,
        Some((b, a)) => (b, a),
        None => (name, ""),
    };
    CARD_PCMS.contains(&base) && args.bytes().all(|b| b.is_ascii_alphanumeric() || b"_=,.-".contains(&b))
}

/// Why a name is refused, in the user's terms.
fn refusal_reason(name: &str) -> &'static str {
    if name.starts_with("sim:file") {
        "file replay needs an operator pattern"
    } else if name.contains('{') || name.contains('}') {
        "an inline plugin definition"
    } else if name.contains('|') {
        "it names a pipe to a command"
    } else if name.contains('/') {
        "it names a file"
    } else if name.contains('\'') || name.contains('"') || name.contains('$') {
        "quoted or variable arguments"
    } else {
        "not a card reference nor a listed PCM"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn listed() -> Vec<DeviceInfo> {
        vec![DeviceInfo { name: "pulse".into(), description: String::new() }]
    }

    #[test]
    fn card_references_sim_devices_and_listed_pcms_pass_by_default() {
        let p = DevicePolicy::default();
        for ok in [
            "hw:1,0",
            "hw:CARD=PCH,DEV=0",
            "plughw:1",
            "dsnoop:0",
            "sysdefault:CARD=PCH",
            "default",
            "sim:pattern",
            "sim:sine",
            "pulse",
        ] {
            assert_eq!(p.check(ok, listed), Ok(()), "{ok}");
        }
    }

    #[test]
    fn plugin_strings_files_pipes_and_file_replay_are_refused_with_the_reason() {
        let p = DevicePolicy::default();
        for (bad, why) in [
            ("file:'|touch /tmp/pwned',raw", "pipe"),
            ("file:'/tmp/x.raw',raw", "names a file"),
            ("plug:{ type file file \"/x\" }", "inline plugin"),
            ("hw:'1'", "quoted"),
            ("hw:$X", "quoted or variable"),
            ("hw:1 ", "not a card reference"),
            ("hwx", "not a card reference"),
            ("bass_jack", "not a card reference"),
            ("sim:file:/tmp/a.wav", "file replay"),
            ("sim:file-loop:/tmp/a.wav", "file replay"),
            ("sim:file-renumber:/tmp/a.wav", "file replay"),
            ("hw:", "not a card reference"),
        ] {
            let e = p.check(bad, listed).unwrap_err();
            assert!(e.contains(why) && e.contains(&format!("{bad:?}")), "{bad}: {e}");
        }
    }

    #[test]
    fn operator_patterns_widen_the_policy_without_path_escapes() {
        let p = DevicePolicy::new(&["sim:file:/data/*".into(), "bass_*".into()]).unwrap();
        assert_eq!(p.check("sim:file:/data/a.wav", listed), Ok(()));
        assert_eq!(p.check("bass_jack", listed), Ok(()));
        assert!(p.check("sim:file:/data/../etc/shadow", listed).is_err());
        assert!(p.check("sim:file:/tmp/a.wav", listed).is_err());
        assert!(DevicePolicy::new(&["[".into()]).unwrap_err().contains("--allow-device"));
    }
}
