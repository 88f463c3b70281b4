//! The C functions of liblsl an outlet needs, resolved by name from the loaded library
//! (declarations of liblsl's `lsl_c.h`, version 1.14 and later).

use std::ffi::{c_char, c_double, c_int, c_ulong, c_void, CStr};
use std::path::Path;

/// LSL's channel formats (`lsl_channel_format_t`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(i32)]
pub enum ChannelFormat {
    /// `cft_string`.
    String = 3,
    /// `cft_int32`.
    Int32 = 4,
}

type CreateStreaminfo =
    unsafe extern "C" fn(*const c_char, *const c_char, i32, c_double, c_int, *const c_char) -> *mut c_void;
type GetDesc = unsafe extern "C" fn(*mut c_void) -> *mut c_void;
type AppendChild = unsafe extern "C" fn(*mut c_void, *const c_char) -> *mut c_void;
type AppendChildValue = unsafe extern "C" fn(*mut c_void, *const c_char, *const c_char) -> *mut c_void;
type DestroyStreaminfo = unsafe extern "C" fn(*mut c_void);
type CreateOutlet = unsafe extern "C" fn(*mut c_void, i32, i32) -> *mut c_void;
type DestroyOutlet = unsafe extern "C" fn(*mut c_void);
type PushChunkItnp = unsafe extern "C" fn(*mut c_void, *const i32, c_ulong, *const c_double, i32) -> i32;
type PushSampleStrtp = unsafe extern "C" fn(*mut c_void, *const *const c_char, c_double, i32) -> i32;
type HaveConsumers = unsafe extern "C" fn(*mut c_void) -> i32;
type LocalClock = unsafe extern "C" fn() -> c_double;
type LibraryVersion = unsafe extern "C" fn() -> i32;

/// The loaded library and its functions (valid while `_lib` is: the struct owns it).
pub struct Api {
    _lib: libloading::Library,
    create_streaminfo: CreateStreaminfo,
    get_desc: GetDesc,
    append_child: AppendChild,
    append_child_value: AppendChildValue,
    destroy_streaminfo: DestroyStreaminfo,
    create_outlet: CreateOutlet,
    destroy_outlet: DestroyOutlet,
    push_chunk_itnp: PushChunkItnp,
    push_sample_strtp: PushSampleStrtp,
    have_consumers: HaveConsumers,
    local_clock: LocalClock,
    library_version: LibraryVersion,
}

impl Api {
    /// Loads `path` (a file, or a name the dynamic loader looks up) and resolves the functions.
    pub fn load(path: &Path) -> Result<Api, String> {
        // SAFETY: loading a shared library runs its initialisers; liblsl's start no threads
        // and touch no state of this process (its threads start with the first outlet).
        let lib = unsafe { libloading::Library::new(path) }.map_err(|e| e.to_string())?;
        /// One symbol as a function pointer of type `T`.
        ///
        /// # Safety
        /// `T` must be the C type of the function named `name` in liblsl's header.
        unsafe fn get<T: Copy>(lib: &libloading::Library, name: &CStr) -> Result<T, String> {
            // SAFETY: the caller names a function of liblsl's C API and its type.
            unsafe { lib.get::<T>(name.to_bytes_with_nul()) }
                .map(|s| *s)
                .map_err(|e| format!("not liblsl ({}: {e})", name.to_string_lossy()))
        }
        // SAFETY: each type is the declaration of that function in liblsl's lsl_c.h; the
        // pointers stay valid while `lib`, which this struct owns, is loaded.
        unsafe {
            Ok(Api {
                create_streaminfo: get(&lib, c"lsl_create_streaminfo")?,
                get_desc: get(&lib, c"lsl_get_desc")?,
                append_child: get(&lib, c"lsl_append_child")?,
                append_child_value: get(&lib, c"lsl_append_child_value")?,
                destroy_streaminfo: get(&lib, c"lsl_destroy_streaminfo")?,
                create_outlet: get(&lib, c"lsl_create_outlet")?,
                destroy_outlet: get(&lib, c"lsl_destroy_outlet")?,
                push_chunk_itnp: get(&lib, c"lsl_push_chunk_itnp")?,
                push_sample_strtp: get(&lib, c"lsl_push_sample_strtp")?,
                have_consumers: get(&lib, c"lsl_have_consumers")?,
                local_clock: get(&lib, c"lsl_local_clock")?,
                library_version: get(&lib, c"lsl_library_version")?,
                _lib: lib,
            })
        }
    }

    pub fn create_streaminfo(
        &self,
        name: &CStr,
        kind: &CStr,
        channels: i32,
        rate: f64,
        format: ChannelFormat,
        source_id: &CStr,
    ) -> *mut c_void {
        // SAFETY: NUL-terminated strings valid for the call (liblsl copies them).
        unsafe {
            (self.create_streaminfo)(
                name.as_ptr(),
                kind.as_ptr(),
                channels,
                rate,
                format as c_int,
                source_id.as_ptr(),
            )
        }
    }

    pub fn get_desc(&self, info: *mut c_void) -> *mut c_void {
        // SAFETY: `info` is a live streaminfo of this library (Lsl::outlet made it).
        unsafe { (self.get_desc)(info) }
    }

    pub fn append_child(&self, e: *mut c_void, name: &CStr) -> *mut c_void {
        // SAFETY: `e` is an element of a live streaminfo's description; `name` is copied.
        unsafe { (self.append_child)(e, name.as_ptr()) }
    }

    pub fn append_child_value(&self, e: *mut c_void, name: &CStr, value: &CStr) -> *mut c_void {
        // SAFETY: as append_child; both strings are copied.
        unsafe { (self.append_child_value)(e, name.as_ptr(), value.as_ptr()) }
    }

    pub fn destroy_streaminfo(&self, info: *mut c_void) {
        // SAFETY: `info` is live and destroyed once (the outlet keeps its own copy).
        unsafe { (self.destroy_streaminfo)(info) }
    }

    pub fn create_outlet(&self, info: *mut c_void, chunk_size: i32, max_buffered: i32) -> *mut c_void {
        // SAFETY: `info` is a live streaminfo; the outlet copies it.
        unsafe { (self.create_outlet)(info, chunk_size, max_buffered) }
    }

    pub fn destroy_outlet(&self, outlet: *mut c_void) {
        // SAFETY: `outlet` is live and destroyed once (Outlet's Drop).
        unsafe { (self.destroy_outlet)(outlet) }
    }

    pub fn push_chunk_itnp(&self, outlet: *mut c_void, data: &[i32], timestamps: &[f64]) -> i32 {
        // SAFETY: `outlet` is live; `data` holds `data.len()` values (a whole number of
        // multiplexed samples, checked by the caller) and `timestamps` one per sample; liblsl
        // copies both before returning.
        unsafe {
            (self.push_chunk_itnp)(outlet, data.as_ptr(), data.len() as c_ulong, timestamps.as_ptr(), 1)
        }
    }

    pub fn push_sample_strtp(&self, outlet: *mut c_void, data: &[*const c_char; 1], timestamp: f64) -> i32 {
        // SAFETY: `outlet` is a live 1-channel string outlet; `data` one NUL-terminated string,
        // valid for the call (copied).
        unsafe { (self.push_sample_strtp)(outlet, data.as_ptr(), timestamp, 1) }
    }

    pub fn have_consumers(&self, outlet: *mut c_void) -> i32 {
        // SAFETY: `outlet` is live.
        unsafe { (self.have_consumers)(outlet) }
    }

    pub fn local_clock(&self) -> f64 {
        // SAFETY: no arguments; reads a clock.
        unsafe { (self.local_clock)() }
    }

    pub fn library_version(&self) -> i32 {
        // SAFETY: no arguments.
        unsafe { (self.library_version)() }
    }
}
