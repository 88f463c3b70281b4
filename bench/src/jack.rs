//! A direct JACK client (libjack loaded with dlopen, so no JACK headers or -dev package are
//! needed): two input ports connected to `system:capture_1/2`; its process callback copies
//! the period and records how long after the period's first frame it runs.

use std::ffi::{c_char, c_int, c_void, CStr, CString};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

type ClientOpen = unsafe extern "C" fn(*const c_char, c_int, *mut c_int, ...) -> *mut c_void;
type SetProcess =
    unsafe extern "C" fn(*mut c_void, extern "C" fn(u32, *mut c_void) -> c_int, *mut c_void) -> c_int;
type PortRegister = unsafe extern "C" fn(*mut c_void, *const c_char, *const c_char, u64, u64) -> *mut c_void;
type Activate = unsafe extern "C" fn(*mut c_void) -> c_int;
type Connect = unsafe extern "C" fn(*mut c_void, *const c_char, *const c_char) -> c_int;
type PortName = unsafe extern "C" fn(*const c_void) -> *const c_char;
type GetBuffer = unsafe extern "C" fn(*mut c_void, u32) -> *mut c_void;
type CycleTimes = unsafe extern "C" fn(*const c_void, *mut u32, *mut u64, *mut u64, *mut f32) -> c_int;
type GetTime = unsafe extern "C" fn() -> u64;

const CAP: usize = 1 << 16;

/// What the process callback needs; lives in a Box for the client's lifetime.
struct Shared {
    client: *mut c_void,
    ports: [*mut c_void; 2],
    get_buffer: GetBuffer,
    cycle_times: CycleTimes,
    get_time: GetTime,
    /// Delay (µs) from the cycle start (the period available) to the callback running.
    delays: Vec<AtomicU64>,
    /// Cycle start (jack_get_time µs) per period.
    starts: Vec<AtomicU64>,
    /// CLOCK_MONOTONIC (ns) minus jack_get_time (ns), measured in the callback.
    offsets: Vec<AtomicU64>,
    count: AtomicUsize,
    copy: [Vec<f32>; 2],
}

/// A running JACK client.
pub struct JackClient {
    lib: *mut c_void,
    shared: Box<Shared>,
}

fn sym<T: Copy>(lib: *mut c_void, name: &str) -> Result<T, String> {
    let c = CString::new(name).map_err(|e| e.to_string())?;
    // SAFETY: `lib` is a live dlopen handle and `c` a NUL-terminated name.
    let p = unsafe { libc::dlsym(lib, c.as_ptr()) };
    if p.is_null() {
        return Err(format!("libjack has no {name}"));
    }
    // SAFETY: T is the function-pointer type of the C declaration of `name` in jack/jack.h;
    // function pointers and data pointers have the same size on Linux.
    Ok(unsafe { std::mem::transmute_copy::<*mut c_void, T>(&p) })
}

extern "C" fn process(nframes: u32, arg: *mut c_void) -> c_int {
    // SAFETY: `arg` is the Box<Shared> registered with the callback; it outlives the client
    // (the client is closed before the box is dropped); only this callback mutates `copy`.
    let s = unsafe { &mut *(arg as *mut Shared) };
    let (mut frames, mut usecs, mut next, mut period) = (0u32, 0u64, 0u64, 0f32);
    // SAFETY: valid client and out-pointers.
    let ok = unsafe { (s.cycle_times)(s.client, &mut frames, &mut usecs, &mut next, &mut period) } == 0;
    for c in 0..2 {
        // SAFETY: a registered port of this client, inside its process callback; JACK audio
        // buffers hold `nframes` f32 samples.
        let buf = unsafe { (s.get_buffer)(s.ports[c], nframes) } as *const f32;
        let n = (nframes as usize).min(s.copy[c].len());
        if !buf.is_null() {
            // SAFETY: see above; the destination holds at least n samples.
            unsafe { std::ptr::copy_nonoverlapping(buf, s.copy[c].as_mut_ptr(), n) };
        }
    }
    if ok {
        // SAFETY: plain function call.
        let now = unsafe { (s.get_time)() };
        let mono = bassport::sys::monotonic_ns();
        let _ = period;
        let i = s.count.fetch_add(1, Ordering::Relaxed);
        if i < s.delays.len() {
            s.delays[i].store(now.saturating_sub(usecs), Ordering::Relaxed);
            s.starts[i].store(usecs, Ordering::Relaxed);
            s.offsets[i].store(mono.wrapping_sub(now * 1000), Ordering::Relaxed);
        }
    }
    0
}

impl JackClient {
    /// Opens a client named `name` on the server `$JACK_DEFAULT_SERVER`, connects
    /// system:capture_1/2 to it and activates it.
    pub fn start(name: &str) -> Result<JackClient, String> {
        let lib_name = CString::new("libjack.so.0").map_err(|e| e.to_string())?;
        // SAFETY: dlopen with a valid name; the handle is closed in Drop.
        let lib = unsafe { libc::dlopen(lib_name.as_ptr(), libc::RTLD_NOW) };
        if lib.is_null() {
            return Err("libjack.so.0 not found (install jackd2)".into());
        }
        // Silence libjack's messages (it prints while the server is still starting).
        type SetMsg = unsafe extern "C" fn(extern "C" fn(*const c_char));
        extern "C" fn quiet(_: *const c_char) {}
        for f in ["jack_set_error_function", "jack_set_info_function"] {
            if let Ok(set) = sym::<SetMsg>(lib, f) {
                // SAFETY: the documented setter, with a callback that ignores its argument.
                unsafe { set(quiet) };
            }
        }
        let open: ClientOpen = sym(lib, "jack_client_open")?;
        let set_process: SetProcess = sym(lib, "jack_set_process_callback")?;
        let register: PortRegister = sym(lib, "jack_port_register")?;
        let activate: Activate = sym(lib, "jack_activate")?;
        let connect: Connect = sym(lib, "jack_connect")?;
        let port_name: PortName = sym(lib, "jack_port_name")?;
        let cname = CString::new(name).map_err(|e| e.to_string())?;
        let mut status = 0;
        // SAFETY: valid name and status pointer; option JackNoStartServer (1), no variadic
        // arguments needed without JackServerName.
        let client = unsafe { open(cname.as_ptr(), 1, &mut status) };
        if client.is_null() {
            return Err(format!("jack_client_open failed (status {status:#x})"));
        }
        let audio = CString::new("32 bit float mono audio").map_err(|e| e.to_string())?;
        let mut ports = [std::ptr::null_mut(); 2];
        for (c, p) in ports.iter_mut().enumerate() {
            let pn = CString::new(format!("in_{}", c + 1)).map_err(|e| e.to_string())?;
            // SAFETY: live client, valid strings; flags JackPortIsInput (1).
            *p = unsafe { register(client, pn.as_ptr(), audio.as_ptr(), 1, 0) };
            if p.is_null() {
                return Err("jack_port_register failed".into());
            }
        }
        let mut shared = Box::new(Shared {
            client,
            ports,
            get_buffer: sym(lib, "jack_port_get_buffer")?,
            cycle_times: sym(lib, "jack_get_cycle_times")?,
            get_time: sym(lib, "jack_get_time")?,
            delays: (0..CAP).map(|_| AtomicU64::new(0)).collect(),
            starts: (0..CAP).map(|_| AtomicU64::new(0)).collect(),
            offsets: (0..CAP).map(|_| AtomicU64::new(0)).collect(),
            count: AtomicUsize::new(0),
            copy: [vec![0.0; 8192], vec![0.0; 8192]],
        });
        let arg = &mut *shared as *mut Shared as *mut c_void;
        // SAFETY: live client; `arg` stays valid until the client is closed (Drop closes it
        // before the box goes).
        unsafe {
            if set_process(client, process, arg) != 0 {
                return Err("jack_set_process_callback failed".into());
            }
            if activate(client) != 0 {
                return Err("jack_activate failed".into());
            }
            for (c, &p) in ports.iter().enumerate() {
                let src = CString::new(format!("system:capture_{}", c + 1)).map_err(|e| e.to_string())?;
                let dst = CStr::from_ptr(port_name(p)).to_owned();
                if connect(client, src.as_ptr(), dst.as_ptr()) != 0 {
                    return Err(format!("jack_connect {src:?} failed"));
                }
            }
        }
        Ok(JackClient { lib, shared })
    }

    /// Clears the recorded delays.
    pub fn reset(&self) {
        self.shared.count.store(0, Ordering::Relaxed);
    }

    /// Delays (ns) from cycle start to callback, recorded since the last reset.
    pub fn delays_ns(&self) -> Vec<f64> {
        let n = self.shared.count.load(Ordering::Relaxed).min(CAP);
        self.shared.delays[..n].iter().map(|d| d.load(Ordering::Relaxed) as f64 * 1000.0).collect()
    }

    /// Cycle start times since the last reset, on CLOCK_MONOTONIC (ns), ascending; and the
    /// spread (max − min, ns) of the measured clock offset (jack_get_time vs CLOCK_MONOTONIC).
    pub fn cycle_starts_mono(&self) -> (Vec<u64>, u64) {
        let n = self.shared.count.load(Ordering::Relaxed).min(CAP);
        let offs: Vec<i64> =
            self.shared.offsets[..n].iter().map(|o| o.load(Ordering::Relaxed) as i64).collect();
        let mut sorted = offs.clone();
        sorted.sort_unstable();
        let off = sorted.get(n / 2).copied().unwrap_or(0);
        let spread = match (sorted.first(), sorted.last()) {
            (Some(a), Some(b)) => (b - a) as u64,
            _ => 0,
        };
        let starts = self.shared.starts[..n]
            .iter()
            .map(|s| (s.load(Ordering::Relaxed) as i64 * 1000 + off) as u64)
            .collect();
        (starts, spread)
    }
}

impl Drop for JackClient {
    fn drop(&mut self) {
        if let Ok(close) = sym::<Activate>(self.lib, "jack_client_close") {
            // SAFETY: the client is live; closing stops the callback before `shared` drops.
            unsafe { close(self.shared.client) };
        }
        // libjack stays loaded: its threads may still be winding down.
    }
}
