//! A JACK client that plays known tones on two output ports (libjack loaded with dlopen, so
//! no JACK headers or -dev package are needed): the signal source of tests that capture the
//! same JACK ports through several ALSA `jack` PCMs.

use std::ffi::{c_char, c_int, c_void, CString};
use std::sync::atomic::{AtomicU64, Ordering};

/// Sample rate the tones are computed for: the rig's jackd runs at this rate.
pub const TONES_RATE: u32 = 48000;

/// The tones of each output port: (frequency in whole Hz, amplitude in full scale). Whole
/// frequencies make the signal repeat every second, so a one-second window of any channel
/// holds each tone in a DFT bin of its own; the low tone (7 and 5 Hz) makes a lag between two
/// captures of the signal unambiguous over ±70 ms, the high ones measure it to a fraction of
/// a sample.
pub const TONES: [[(u32, f64); 3]; 2] =
    [[(7, 0.25), (997, 0.25), (4001, 0.125)], [(5, 0.25), (440, 0.25), (2503, 0.125)]];

/// The value the player writes on port `port` (0 or 1) at its own frame `n`.
pub fn tone_sample(port: usize, n: u64) -> f64 {
    let phase = (n % u64::from(TONES_RATE)) as f64 / f64::from(TONES_RATE);
    TONES[port].iter().map(|&(f, a)| a * (std::f64::consts::TAU * f64::from(f) * phase).sin()).sum()
}

type ClientOpen = unsafe extern "C" fn(*const c_char, c_int, *mut c_int, ...) -> *mut c_void;
type Process = extern "C" fn(u32, *mut c_void) -> c_int;
type SetProcess = unsafe extern "C" fn(*mut c_void, Process, *mut c_void) -> c_int;
type PortRegister = unsafe extern "C" fn(*mut c_void, *const c_char, *const c_char, u64, u64) -> *mut c_void;
type ClientCall = unsafe extern "C" fn(*mut c_void) -> c_int;
type GetBuffer = unsafe extern "C" fn(*mut c_void, u32) -> *mut c_void;

/// What the process callback needs; boxed for the client's lifetime.
struct Shared {
    ports: [*mut c_void; 2],
    get_buffer: GetBuffer,
    /// Frames played so far (the player's own frame counter).
    played: AtomicU64,
}

/// A running tone player: JACK client `name` with output ports `out_1` and `out_2`
/// ([`TONES`]), closed on drop.
pub struct JackTones {
    lib: *mut c_void,
    client: *mut c_void,
    _shared: Box<Shared>,
}

fn sym<T: Copy>(lib: *mut c_void, name: &str) -> Result<T, String> {
    let c = CString::new(name).map_err(|e| e.to_string())?;
    // SAFETY: `lib` is a live dlopen handle and `c` a NUL-terminated name.
    let p = unsafe { libc::dlsym(lib, c.as_ptr()) };
    if p.is_null() {
        return Err(format!("libjack has no {name}"));
    }
    // SAFETY: T is the function-pointer type of `name`'s declaration in jack/jack.h;
    // function and data pointers have the same size on Linux.
    Ok(unsafe { std::mem::transmute_copy::<*mut c_void, T>(&p) })
}

extern "C" fn process(nframes: u32, arg: *mut c_void) -> c_int {
    // SAFETY: `arg` is the Box<Shared> registered with the callback; the client is closed
    // (which stops the callback) before the box is dropped; the callback only reads it.
    let s = unsafe { &*(arg as *const Shared) };
    let first = s.played.fetch_add(u64::from(nframes), Ordering::Relaxed);
    for (c, &port) in s.ports.iter().enumerate() {
        // SAFETY: a registered port of this client, inside its process callback.
        let buf = unsafe { (s.get_buffer)(port, nframes) } as *mut f32;
        if buf.is_null() {
            continue;
        }
        // SAFETY: a JACK audio buffer holds `nframes` f32 samples, ours to write this cycle.
        let out = unsafe { std::slice::from_raw_parts_mut(buf, nframes as usize) };
        for (i, o) in out.iter_mut().enumerate() {
            *o = tone_sample(c, first + i as u64) as f32;
        }
    }
    0
}

impl JackTones {
    /// Opens client `name` (exactly that name) on the jackd named `server` and activates it.
    pub fn start(name: &str, server: &str) -> Result<JackTones, String> {
        let lib_name = CString::new("libjack.so.0").map_err(|e| e.to_string())?;
        // SAFETY: dlopen with a valid name; the handle is closed in Drop.
        let lib = unsafe { libc::dlopen(lib_name.as_ptr(), libc::RTLD_NOW) };
        if lib.is_null() {
            return Err("libjack.so.0 not found (install jackd2)".into());
        }
        let mut t = JackTones {
            lib,
            client: std::ptr::null_mut(),
            _shared: Box::new(Shared {
                ports: [std::ptr::null_mut(); 2],
                get_buffer: sym(lib, "jack_port_get_buffer")?,
                played: AtomicU64::new(0),
            }),
        };
        let open: ClientOpen = sym(lib, "jack_client_open")?;
        let set_process: SetProcess = sym(lib, "jack_set_process_callback")?;
        let register: PortRegister = sym(lib, "jack_port_register")?;
        let activate: ClientCall = sym(lib, "jack_activate")?;
        let cname = CString::new(name).map_err(|e| e.to_string())?;
        let sname = CString::new(server).map_err(|e| e.to_string())?;
        let mut status = 0;
        // SAFETY: valid name and status pointer; options JackNoStartServer | JackUseExactName
        // | JackServerName (1 | 2 | 4): the last takes the server's name as the one variadic
        // argument.
        t.client = unsafe { open(cname.as_ptr(), 7, &mut status, sname.as_ptr()) };
        if t.client.is_null() {
            return Err(format!("jack_client_open {name:?} failed (status {status:#x})"));
        }
        let audio = CString::new("32 bit float mono audio").map_err(|e| e.to_string())?;
        let mut ports = [std::ptr::null_mut(); 2];
        for (c, p) in ports.iter_mut().enumerate() {
            let pn = CString::new(format!("out_{}", c + 1)).map_err(|e| e.to_string())?;
            // SAFETY: live client, valid strings; flags JackPortIsOutput (2).
            *p = unsafe { register(t.client, pn.as_ptr(), audio.as_ptr(), 2, 0) };
            if p.is_null() {
                return Err("jack_port_register failed".into());
            }
        }
        t._shared.ports = ports;
        let arg = &*t._shared as *const Shared as *mut c_void;
        // SAFETY: live client; `arg` stays valid until the client is closed (Drop closes the
        // client before the box goes).
        unsafe {
            if set_process(t.client, process, arg) != 0 {
                return Err("jack_set_process_callback failed".into());
            }
            if activate(t.client) != 0 {
                return Err("jack_activate failed".into());
            }
        }
        Ok(t)
    }
}

impl Drop for JackTones {
    fn drop(&mut self) {
        if !self.client.is_null() {
            if let Ok(close) = sym::<ClientCall>(self.lib, "jack_client_close") {
                // SAFETY: the client is live; closing it stops the callback before `_shared`
                // drops.
                unsafe { close(self.client) };
            }
        }
        // SAFETY: the handle from dlopen; nothing of the library is used after this.
        unsafe { libc::dlclose(self.lib) };
    }
}
