/* bass_mex: the Matlab / GNU Octave MEX gateway of bass, in C over include/bass.h only.
 *
 *   v                      = bass_mex('Version')
 *   epoch                  = bass_mex('Acquire', device, sampleRate, nFramesPerChunk, nChunksOnPort [, channels [, broker]])
 *                            device: a string, or a cell array {master, follower, ...}; channels: one count, or one per device
 *                            bass_mex('Stop' [, broker])
 *   s                      = bass_mex('Status' [, broker])            struct
 *   devices                = bass_mex('ListDevices' [, broker])       n x 2 cell {name, description}; printed if nargout = 0
 *   h                      = bass_mex('Open' [, name])                 port handle (uint64)
 *                            bass_mex('Close', h)
 *   info                   = bass_mex('Info', h)                       struct: every field of bass_port_info
 *   ci                     = bass_mex('ChunkInfo', h, frame)           struct: the chunk holding frame
 *   [l, r, nfr, n, loss]   = bass_mex('GetAudioData', h, N, nfr [, noLoss])
 *   [x, nfr, n, loss]      = bass_mex('GetAudioDataMulti', h, N, nfr)   x: n x channels int32
 *   lfi                    = bass_mex('Wait', h, frame [, timeoutSeconds])
 *   w                      = bass_mex('WriterCreate', name, device, rate, nfpc, ncop, channels)
 *   lfi                    = bass_mex('Publish', w, int32 interleaved samples)
 *                            bass_mex('WriterClose', w)
 *
 * GetAudioData is the formal getAudioData: l and r are int32 columns of n frames, nfr (uint64)
 * the next frame to read, loss the frames that left the window first. With noLoss true, a
 * loss raises bass:lost instead. Wait blocks until `frame` is published, in slices of 100 ms
 * so that Ctrl-C returns to the prompt (error bass:interrupted); timeoutSeconds Inf (the
 * default) waits forever.
 *
 * ChunkInfo describes the chunk that holds `frame`: firstFrame, monoNs, realtimeNs (uint64),
 * frames, flags (the BASS_CHUNK_* bits) and one logical per flag: gap (zero-filled frames the
 * device or the network did not deliver), discontinuity, timeEstimated, late (delivered in a
 * catch-up burst). A frame that left the window is bass:lost, one not yet published bass:notYet.
 *
 * GetAudioData and GetAudioDataMulti never block; when they return fewer frames than asked,
 * they ask the library whether the port was replaced by a new acquisition (bass:restarted:
 * Close and Open again) or its broker died (bass:writerGone), so a broker restart is never
 * read as "no data yet" forever.
 *
 * Numeric arguments are checked before use: real, finite, integral, within the C type, and
 * not text (bass:badArgument, naming the argument). Handles are this MEX's own: a slot and a
 * per-load generation, so a handle from before `clear functions` / `clear mex` is
 * bass:invalidHandle, never another port; everything still open is closed when the MEX is
 * unloaded (mexAtExit).
 *
 * Errors carry identifiers bass:<code> (bass:noPort, bass:noBroker, bass:timeout,
 * bass:stopped, bass:device, bass:restarted, bass:writerGone, bass:lost, ...) and the
 * library's message. Build: `mkoctfile --mex` (Octave) or `mex` (Matlab), see matlab/README.md.
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bass.h"
#include "mex.h"

/* The tables of bass.h facts (error ids, struct fields, flags), generated with bass.h from the
 * library's Rust definitions by `make header`. */
#include "bass_mex_tables.h"

/* Interrupt flags of the host, resolved at load time if present (weak: absent is NULL).
 * GNU Octave: octave_signal_caught / octave_interrupt_state (liboctave, C linkage).
 * Matlab: utIsInterruptPending (libut, undocumented but long-standing). */
extern volatile sig_atomic_t octave_signal_caught __attribute__((weak));
extern sig_atomic_t octave_interrupt_state __attribute__((weak));
extern bool utIsInterruptPending(void) __attribute__((weak));

static int interrupt_pending(void) {
    if (&octave_interrupt_state && octave_interrupt_state > 0) return 1;
    if (&octave_signal_caught && octave_signal_caught) return 1;
    if (utIsInterruptPending && utIsInterruptPending()) return 1;
    return 0;
}


static const char *error_id(bass_result r) {
    unsigned i = (unsigned)r;
    return i < sizeof IDS / sizeof IDS[0] && IDS[i] ? IDS[i] : "bass:unknown";
}

/* Raises the Matlab error for a failed call (does not return). */
static void fail(const char *call, bass_result r) {
    const char *detail = bass_last_error();
    mexErrMsgIdAndTxt(error_id(r), "%s [%s]", *detail ? detail : call, bass_result_str(r));
}

static void check(const char *call, bass_result r) {
    if (r != BASS_OK) fail(call, r);
}

static void usage(const char *msg) { mexErrMsgIdAndTxt("bass:usage", "bass_mex: %s", msg); }

/* The string argument i (the caller frees it with mxFree), or NULL if absent or empty. */
static char *opt_string(int nrhs, const mxArray *prhs[], int i) {
    if (i >= nrhs || mxIsEmpty(prhs[i])) return NULL;
    if (!mxIsChar(prhs[i])) usage("expected a string argument");
    return mxArrayToString(prhs[i]);
}

static void bad_argument(const char *what, const char *must) {
    mexErrMsgIdAndTxt("bass:badArgument", "bass_mex: %s must be %s", what, must);
}

/* A non-negative integer argument no larger than `max`, given as any real numeric class
 * (int64/uint64 exactly); text, logicals, NaN, Inf, fractions and out-of-range values are
 * bass:badArgument errors naming `what`. */
static uint64_t arg_uint(const mxArray *a, const char *what, uint64_t max) {
    if (!mxIsNumeric(a) || mxIsComplex(a) || mxGetNumberOfElements(a) != 1)
        bad_argument(what, "a real numeric scalar (not text, logical or an array)");
    uint64_t v;
    if (mxIsUint64(a)) {
        v = *(const uint64_t *)mxGetData(a);
    } else if (mxIsInt64(a)) {
        int64_t i = *(const int64_t *)mxGetData(a);
        if (i < 0) bad_argument(what, ">= 0");
        v = (uint64_t)i;
    } else {
        double d = mxGetScalar(a);
        if (isnan(d) || isinf(d)) bad_argument(what, "finite");
        if (d < 0) bad_argument(what, ">= 0");
        if (d != floor(d)) bad_argument(what, "a whole number");
        if (d >= 18446744073709551616.0) bad_argument(what, "below 2^64");
        v = (uint64_t)d;
    }
    if (v > max)
        mexErrMsgIdAndTxt("bass:badArgument", "bass_mex: %s = %llu is out of range (at most %llu)", what,
                          (unsigned long long)v, (unsigned long long)max);
    return v;
}

static uint64_t arg_u64(const mxArray *a, const char *what) { return arg_uint(a, what, UINT64_MAX); }

static uint32_t arg_u32(const mxArray *a, const char *what) { return (uint32_t)arg_uint(a, what, UINT32_MAX); }

/* A timeout in seconds: >= 0, Inf for none, not NaN. */
static double arg_seconds(const mxArray *a, const char *what) {
    if (!mxIsNumeric(a) || mxIsComplex(a) || mxGetNumberOfElements(a) != 1)
        bad_argument(what, "a real numeric scalar in seconds (not text, logical or an array)");
    double d = mxGetScalar(a);
    if (isnan(d) || d < 0) bad_argument(what, ">= 0 seconds (Inf: no limit)");
    return d;
}

/* A true/false flag: a logical or numeric scalar. */
static int arg_flag(const mxArray *a, const char *what) {
    if (mxIsLogical(a) && mxGetNumberOfElements(a) == 1) return mxIsLogicalScalarTrue(a);
    if (!mxIsNumeric(a) || mxIsComplex(a) || mxGetNumberOfElements(a) != 1) bad_argument(what, "true or false");
    double d = mxGetScalar(a);
    if (isnan(d)) bad_argument(what, "true or false");
    return d != 0;
}

static mxArray *u64_scalar(uint64_t v) {
    mxArray *m = mxCreateNumericMatrix(1, 1, mxUINT64_CLASS, mxREAL);
    *(uint64_t *)mxGetData(m) = v;
    return m;
}

/* ---- Handles: (generation << 32) | serial number (from 1, never reused in a load). ----
 * The generation is unique for each load of this MEX in the process: it is counted in an
 * environment variable, which outlives the MEX's own memory across `clear mex`. */
enum kind { FREE = 0, PORT = 1, WRITER = 2 };
struct slot {
    enum kind kind;
    uint32_t serial;
    void *ptr;
};
static struct slot *slots;
static uint32_t n_slots, last_serial;
static uint64_t generation;
static const char GENERATION_VAR[] = "BASS_MEX_LOAD_GENERATION";

/* mexAtExit: closes everything this load opened (ports first, then writers). */
static void unload(void) {
    for (uint32_t i = 0; i < n_slots; i++) {
        if (slots[i].kind == PORT) bass_port_close((bass_port *)slots[i].ptr);
    }
    for (uint32_t i = 0; i < n_slots; i++) {
        if (slots[i].kind == WRITER) bass_writer_close((bass_writer *)slots[i].ptr);
    }
    free(slots);
    slots = NULL;
    n_slots = 0;
    last_serial = 0;
    generation = 0;
}

static void loaded(void) {
    if (generation) return;
    const char *prev = getenv(GENERATION_VAR);
    uint64_t g = prev ? strtoull(prev, NULL, 10) : 0;
    generation = (g + 1) & 0x1FFFFF; /* handles stay exact in a double: 21 + 32 bits */
    if (!generation) generation = 1;
    char text[24];
    snprintf(text, sizeof text, "%llu", (unsigned long long)generation);
    setenv(GENERATION_VAR, text, 1);
    mexAtExit(unload);
}

static uint64_t handle_new(enum kind kind, void *ptr) {
    if (last_serial == UINT32_MAX) {
        if (kind == PORT) bass_port_close((bass_port *)ptr);
        else bass_writer_close((bass_writer *)ptr);
        mexErrMsgIdAndTxt("bass:io", "bass_mex: handle numbers exhausted; clear mex to start again");
    }
    uint32_t i = 0;
    while (i < n_slots && slots[i].kind != FREE) i++;
    if (i == n_slots) {
        uint32_t grown = n_slots ? 2 * n_slots : 16;
        struct slot *s = grown < n_slots ? NULL : realloc(slots, grown * sizeof *s);
        if (!s) {
            if (kind == PORT) bass_port_close((bass_port *)ptr);
            else bass_writer_close((bass_writer *)ptr);
            mexErrMsgIdAndTxt("bass:io", "bass_mex: out of memory for handles");
        }
        memset(s + n_slots, 0, (grown - n_slots) * sizeof *s);
        slots = s;
        n_slots = grown;
    }
    slots[i].kind = kind;
    slots[i].serial = ++last_serial;
    slots[i].ptr = ptr;
    return generation << 32 | (uint64_t)slots[i].serial;
}

/* The slot of handle argument i of `kind`; bass:invalidHandle if closed, forged or stale. */
static struct slot *handle_arg(int nrhs, const mxArray *prhs[], int i, enum kind kind) {
    const char *what = kind == PORT ? "port handle" : "writer handle";
    if (i >= nrhs) mexErrMsgIdAndTxt("bass:usage", "bass_mex: missing %s", what);
    uint64_t h = arg_u64(prhs[i], what);
    uint64_t gen = h >> 32, k = h & 0xFFFFFFFFu;
    if (gen != generation)
        mexErrMsgIdAndTxt("bass:invalidHandle",
                          "bass_mex: %s %llu is from %s load of bass_mex (cleared by clear functions or clear mex)",
                          what, (unsigned long long)h, gen ? "an earlier" : "no");
    for (uint32_t j = 0; k && j < n_slots; j++) {
        if (slots[j].kind == kind && slots[j].serial == k) return &slots[j];
    }
    mexErrMsgIdAndTxt("bass:invalidHandle", "bass_mex: %s %llu is closed or unknown", what, (unsigned long long)h);
    return NULL; /* not reached */
}

static bass_port *port_arg(int nrhs, const mxArray *prhs[], int i) {
    return (bass_port *)handle_arg(nrhs, prhs, i, PORT)->ptr;
}

static bass_writer *writer_arg(int nrhs, const mxArray *prhs[], int i) {
    return (bass_writer *)handle_arg(nrhs, prhs, i, WRITER)->ptr;
}

/* After a read that returned fewer frames than asked: raises bass:restarted if a new
 * acquisition replaced the port, bass:writerGone if its broker died (as bass_port_wait
 * reports them; a zero timeout does not block). Stopped and device-error ports keep
 * returning n = 0 (their state is in Info). */
static void check_replaced(const char *call, bass_port *port, uint64_t nfr) {
    uint64_t lfi = 0;
    bass_result r = bass_port_wait(port, nfr, 0, &lfi);
    if (r == BASS_ERR_RESTARTED || r == BASS_ERR_WRITER_GONE) fail(call, r);
}

/* State names come from the library (bass_state_str: one exhaustive table in Rust, checked
 * against include/bass.h by the tests), so a new state is never shown as "unknown". */
static const char *state_name(uint32_t s) { return bass_state_str(s); }

#define COUNT(a) (sizeof(a) / sizeof((a)[0]))

static mxArray *field_value(const char *base, const struct field_map *f) {
    const char *p = base + f->offset;
    uint32_t u32;
    uint64_t u64;
    double d;
    switch (f->kind) {
    case AS_DOUBLE_U32:
        memcpy(&u32, p, sizeof u32);
        return mxCreateDoubleScalar(u32);
    case AS_DOUBLE_U64:
        memcpy(&u64, p, sizeof u64);
        return mxCreateDoubleScalar((double)u64);
    case AS_UINT64:
        memcpy(&u64, p, sizeof u64);
        return u64_scalar(u64);
    case AS_DOUBLE:
        memcpy(&d, p, sizeof d);
        return mxCreateDoubleScalar(d);
    case AS_LOGICAL:
        memcpy(&u32, p, sizeof u32);
        return mxCreateLogicalScalar(u32 != 0);
    case AS_STATE:
        memcpy(&u32, p, sizeof u32);
        return mxCreateString(state_name(u32));
    case AS_TEXT:
        return mxCreateString(p);
    }
    return mxCreateDoubleMatrix(0, 0, mxREAL); /* not reached */
}

/* A 1x1 struct with the `n` mapped fields of the C struct at `base`, and `extra` more
 * fields (named in `extra_names`) left for the caller to fill. */
static mxArray *mapped_struct(const void *base, const struct field_map *fields, size_t n, const char *const *extra_names,
                              size_t extra) {
    const char *names[32];
    if (n + extra > COUNT(names)) mexErrMsgIdAndTxt("bass:panic", "bass_mex: too many struct fields");
    for (size_t k = 0; k < n; k++) names[k] = fields[k].name;
    for (size_t k = 0; k < extra; k++) names[n + k] = extra_names[k];
    mxArray *s = mxCreateStructMatrix(1, 1, (int)(n + extra), names);
    for (size_t k = 0; k < n; k++) mxSetFieldByNumber(s, 0, (int)k, field_value((const char *)base, &fields[k]));
    return s;
}

static mxArray *info_struct(const bass_port_info *i) { return mapped_struct(i, INFO_FIELDS, COUNT(INFO_FIELDS), NULL, 0); }

/* The chunk's members, one logical per BASS_CHUNK_* flag (gap, late, ...), then what format
 * 2.4's extension row adds: boundNs (double, NaN if not known) and the channel masks. */
static mxArray *chunk_struct(const bass_chunk_info *c, const bass_chunk_ext *x) {
    static const char *const ext[] = {"boundNs", "missingChannels", "unalignedChannels"};
    const char *names[COUNT(CHUNK_FLAGS) + COUNT(ext)];
    for (size_t k = 0; k < COUNT(CHUNK_FLAGS); k++) names[k] = CHUNK_FLAGS[k].name;
    for (size_t k = 0; k < COUNT(ext); k++) names[COUNT(CHUNK_FLAGS) + k] = ext[k];
    mxArray *s = mapped_struct(c, CHUNK_FIELDS, COUNT(CHUNK_FIELDS), names, COUNT(names));
    for (size_t k = 0; k < COUNT(CHUNK_FLAGS); k++)
        mxSetField(s, 0, CHUNK_FLAGS[k].name, mxCreateLogicalScalar((c->flags & CHUNK_FLAGS[k].bit) != 0));
    double bound = x->bound_ns == BASS_BOUND_UNKNOWN ? mxGetNaN() : (double)x->bound_ns;
    mxSetField(s, 0, "boundNs", mxCreateDoubleScalar(bound));
    mxSetField(s, 0, "missingChannels", u64_scalar(x->missing_channels));
    mxSetField(s, 0, "unalignedChannels", u64_scalar(x->unaligned_channels));
    return s;
}

/* The broker's status; `replica` is the mirror's account of its replica (a struct of
 * REPLICA_FIELDS), or [] for a broker that is not a replica; `devices` a cell array of the
 * acquisition's devices (structs of DEVICE_FIELDS, master first; docs/multi-device.md). */
static mxArray *status_struct(const bass_broker_status *st, const bass_replica_info *replica,
                              const bass_device_info *devs, size_t n_devs) {
    static const char *const extra[] = {"replica", "devices"};
    mxArray *s = mapped_struct(st, STATUS_FIELDS, COUNT(STATUS_FIELDS), extra, 2);
    mxArray *r = replica ? mapped_struct(replica, REPLICA_FIELDS, COUNT(REPLICA_FIELDS), NULL, 0)
                         : mxCreateDoubleMatrix(0, 0, mxREAL);
    mxSetField(s, 0, "replica", r);
    mxArray *d = mxCreateCellMatrix(1, n_devs);
    for (size_t k = 0; k < n_devs; k++)
        mxSetCell(d, k, mapped_struct(&devs[k], DEVICE_FIELDS, COUNT(DEVICE_FIELDS), NULL, 0));
    mxSetField(s, 0, "devices", d);
    return s;
}

/* The channel counts of `n` devices: one count for all (a scalar) or one per device (a real
 * double vector of n whole numbers); 0 means 2. */
static void arg_channels(const mxArray *a, size_t n, uint32_t *out) {
    if (mxGetNumberOfElements(a) == 1) {
        uint32_t c = arg_u32(a, "channels");
        for (size_t k = 0; k < n; k++) out[k] = c;
        return;
    }
    if (!mxIsDouble(a) || mxIsComplex(a) || mxGetNumberOfElements(a) != n)
        bad_argument("channels", "a whole number, or a real vector of one whole number per device");
    const double *d = (const double *)mxGetData(a);
    for (size_t k = 0; k < n; k++) {
        if (!(d[k] >= 0 && d[k] <= (double)UINT32_MAX && d[k] == floor(d[k])))
            bad_argument("channels", "whole numbers from 0 to 2^32 - 1, one per device");
        out[k] = (uint32_t)d[k];
    }
}

/* device: a string, or a cell array of strings (the master first, then its followers;
 * docs/multi-device.md); channels: a scalar for every device or one count per device. */
static void cmd_acquire(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    if (nrhs < 5) usage("Acquire needs device, sampleRate, nFramesPerChunk, nChunksOnPort");
    size_t n = mxIsCell(prhs[1]) ? mxGetNumberOfElements(prhs[1]) : 1;
    if (mxIsCell(prhs[1])) {
        if (n == 0 || n > 64) bad_argument("device", "a cell array of 1 to 64 device names");
        for (size_t k = 0; k < n; k++) {
            const mxArray *c = mxGetCell(prhs[1], k);
            if (!c || !mxIsChar(c) || mxIsEmpty(c)) bad_argument("device", "a cell array of non-empty strings");
        }
    } else if (!mxIsChar(prhs[1]) || mxIsEmpty(prhs[1])) {
        bad_argument("device", "a non-empty string or a cell array of them");
    }
    uint32_t rate = arg_u32(prhs[2], "sampleRate");
    uint32_t nfpc = arg_u32(prhs[3], "nFramesPerChunk");
    uint32_t ncop = arg_u32(prhs[4], "nChunksOnPort");
    uint32_t channels[64] = {0};
    if (nrhs > 5 && !mxIsEmpty(prhs[5])) arg_channels(prhs[5], n, channels);
    if (nrhs > 6 && !mxIsEmpty(prhs[6]) && !mxIsChar(prhs[6])) bad_argument("broker", "a string");
    char *broker = opt_string(nrhs, prhs, 6);
    uint64_t epoch = 0;
    bass_result r;
    if (mxIsCell(prhs[1])) {
        char *names[64];
        for (size_t k = 0; k < n; k++) names[k] = mxArrayToString(mxGetCell(prhs[1], k));
        r = bass_acquire_devices_channels(broker, (const char *const *)names, channels, n, rate, nfpc, ncop,
                                          &epoch);
        for (size_t k = 0; k < n; k++) mxFree(names[k]);
    } else {
        char *device = opt_string(nrhs, prhs, 1);
        r = bass_acquire(broker, device, rate, nfpc, ncop, channels[0], &epoch);
        mxFree(device);
    }
    if (broker) mxFree(broker);
    check("Acquire", r);
    if (nlhs > 0) plhs[0] = u64_scalar(epoch);
}

static void cmd_list_devices(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    char *broker = opt_string(nrhs, prhs, 1);
    size_t need = 0;
    bass_result r = bass_list_devices(broker, NULL, 0, &need);
    char *buf = NULL;
    if (r == BASS_ERR_BUFFER_TOO_SMALL) {
        buf = mxCalloc(need + 1, 1);
        r = bass_list_devices(broker, buf, need + 1, &need);
    }
    if (broker) mxFree(broker);
    check("ListDevices", r);
    size_t lines = 0;
    for (const char *p = buf; p && *p; p++) lines += *p == '\n';
    mxArray *cell = mxCreateCellMatrix(lines, 2);
    size_t k = 0;
    for (char *line = buf; line && *line && k < lines; k++) {
        char *nl = strchr(line, '\n');
        *nl = 0;
        char *tab = strchr(line, '\t');
        if (tab) *tab = 0;
        if (nlhs == 0) mexPrintf("%-24s %s\n", line, tab ? tab + 1 : "");
        mxSetCell(cell, k, mxCreateString(line));
        mxSetCell(cell, k + lines, mxCreateString(tab ? tab + 1 : ""));
        line = nl + 1;
    }
    if (buf) mxFree(buf);
    if (nlhs > 0) plhs[0] = cell;
    else mxDestroyArray(cell);
}

static void cmd_get_audio_data(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    if (nrhs < 4) usage("GetAudioData needs a port handle, N and nfr");
    uint64_t n_req = arg_uint(prhs[2], "N", SIZE_MAX);
    uint64_t nfr = arg_u64(prhs[3], "nfr");
    int no_loss = nrhs > 4 && arg_flag(prhs[4], "noLoss");
    bass_port *port = port_arg(nrhs, prhs, 1);
    bass_port_info info;
    check("GetAudioData", bass_port_get_info(port, &info));
    /* At most nFOP frames can come back: allocate no more than that. */
    size_t cap = (size_t)(n_req < info.frames_on_port ? n_req : info.frames_on_port);
    mxArray *l = mxCreateNumericMatrix(cap ? cap : 1, 1, mxINT32_CLASS, mxREAL);
    mxArray *r = mxCreateNumericMatrix(cap ? cap : 1, 1, mxINT32_CLASS, mxREAL);
    size_t n = 0;
    uint64_t loss = 0, nfr_in = nfr;
    bass_result res = bass_get_audio_data(port, cap, &nfr, (int32_t *)mxGetData(l), (int32_t *)mxGetData(r), &n, &loss);
    if (res != BASS_OK) {
        mxDestroyArray(l);
        mxDestroyArray(r);
        fail("GetAudioData", res);
    }
    if (no_loss && loss) {
        mxDestroyArray(l);
        mxDestroyArray(r);
        mexErrMsgIdAndTxt("bass:lost", "GetAudioData: %llu frames from frame %llu left the port before they were read",
                          (unsigned long long)loss, (unsigned long long)nfr_in);
    }
    if (n < cap) check_replaced("GetAudioData", port, nfr);
    mxSetM(l, n);
    mxSetM(r, n);
    plhs[0] = l;
    if (nlhs > 1) plhs[1] = r;
    else mxDestroyArray(r);
    if (nlhs > 2) plhs[2] = u64_scalar(nfr);
    if (nlhs > 3) plhs[3] = mxCreateDoubleScalar((double)n);
    if (nlhs > 4) plhs[4] = mxCreateDoubleScalar((double)loss);
}

static void cmd_get_audio_data_multi(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    if (nrhs < 4) usage("GetAudioDataMulti needs a port handle, N and nfr");
    uint64_t n_req = arg_uint(prhs[2], "N", SIZE_MAX);
    uint64_t nfr = arg_u64(prhs[3], "nfr");
    bass_port *port = port_arg(nrhs, prhs, 1);
    bass_port_info info;
    check("GetAudioDataMulti", bass_port_get_info(port, &info));
    size_t cap = (size_t)(n_req < info.frames_on_port ? n_req : info.frames_on_port);
    size_t rows = cap ? cap : 1, channels = info.channels;
    /* One int32 column per channel, contiguous: column c starts at c * rows. */
    mxArray *x = mxCreateNumericMatrix(rows, channels, mxINT32_CLASS, mxREAL);
    int32_t *base = (int32_t *)mxGetData(x);
    int32_t *ptrs[BASS_MAX_CHANNELS];
    for (size_t c = 0; c < channels && c < BASS_MAX_CHANNELS; c++) ptrs[c] = base + c * rows;
    size_t n = 0;
    uint64_t loss = 0;
    bass_result res = bass_get_audio_data_multi(port, cap, &nfr, ptrs, channels, &n, &loss);
    if (res != BASS_OK) {
        mxDestroyArray(x);
        fail("GetAudioDataMulti", res);
    }
    if (n < cap) check_replaced("GetAudioDataMulti", port, nfr); /* x is freed by the error */
    /* Keep the first n rows of each column. */
    mxArray *y = mxCreateNumericMatrix(n, channels, mxINT32_CLASS, mxREAL);
    int32_t *dst = (int32_t *)mxGetData(y);
    for (size_t c = 0; c < channels && n; c++) memcpy(dst + c * n, base + c * rows, n * sizeof(int32_t));
    mxDestroyArray(x);
    plhs[0] = y;
    if (nlhs > 1) plhs[1] = u64_scalar(nfr);
    if (nlhs > 2) plhs[2] = mxCreateDoubleScalar((double)n);
    if (nlhs > 3) plhs[3] = mxCreateDoubleScalar((double)loss);
}

static double monotonic_s(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

/* Wait in slices of at most 100 ms against a deadline on the monotonic clock, so that any
 * timeout (fractions of a millisecond, 0, Inf) ends when due and Ctrl-C is seen promptly. */
static void cmd_wait(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    if (nrhs < 3) usage("Wait needs a port handle, a frame index [and timeoutSeconds]");
    uint64_t frame = arg_u64(prhs[2], "frame");
    double timeout = nrhs > 3 ? arg_seconds(prhs[3], "timeoutSeconds") : INFINITY;
    bass_port *port = port_arg(nrhs, prhs, 1);
    double deadline = monotonic_s() + timeout; /* Inf stays Inf */
    uint64_t lfi = 0;
    for (;;) {
        double left_ms = (deadline - monotonic_s()) * 1000.0;
        uint32_t slice = left_ms >= 100.0 ? 100u : left_ms > 0 ? (uint32_t)ceil(left_ms) : 0u;
        bass_result r = bass_port_wait(port, frame, slice, &lfi);
        if (r == BASS_OK) break;
        if (r == BASS_ERR_INTERRUPTED || interrupt_pending())
            mexErrMsgIdAndTxt("bass:interrupted", "Wait: interrupted while waiting for frame %llu",
                              (unsigned long long)frame);
        if (r != BASS_ERR_TIMEOUT) fail("Wait", r);
        if (slice == 0 || monotonic_s() >= deadline) fail("Wait", r);
    }
    (void)nlhs;
    plhs[0] = u64_scalar(lfi);
}

void mexFunction(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    if (nrhs < 1 || !mxIsChar(prhs[0])) usage("the first argument is a command, e.g. 'GetAudioData'");
    char cmd[32];
    if (mxGetString(prhs[0], cmd, sizeof cmd)) usage("unknown command");
    loaded();

    if (!strcmp(cmd, "Version")) {
        plhs[0] = mxCreateString(bass_version());
    } else if (!strcmp(cmd, "Acquire")) {
        cmd_acquire(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "Stop")) {
        char *broker = opt_string(nrhs, prhs, 1);
        bass_result r = bass_stop(broker);
        if (broker) mxFree(broker);
        check("Stop", r);
    } else if (!strcmp(cmd, "Status")) {
        char *broker = opt_string(nrhs, prhs, 1);
        bass_broker_status st;
        bass_replica_info rep;
        bass_result r = bass_status(broker, &st);
        bass_result rr = r == BASS_OK ? bass_replica_status(broker, &rep) : BASS_ERR_NOT_FOUND;
        bass_device_info devs[BASS_MAX_DEVICES];
        size_t n_devs = 0;
        bass_result rd = BASS_OK;
        while (r == BASS_OK && rr == BASS_ERR_NOT_FOUND && n_devs < BASS_MAX_DEVICES) {
            rd = bass_broker_device_info(broker, (uint32_t)n_devs, &devs[n_devs]);
            if (rd != BASS_OK) break;
            n_devs++;
        }
        if (broker) mxFree(broker);
        check("Status", r);
        if (rr != BASS_OK && rr != BASS_ERR_NOT_FOUND) check("Status", rr);
        if (rd != BASS_OK && rd != BASS_ERR_NOT_FOUND) check("Status", rd);
        plhs[0] = status_struct(&st, rr == BASS_OK ? &rep : NULL, devs, n_devs);
    } else if (!strcmp(cmd, "ListDevices")) {
        cmd_list_devices(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "Open")) {
        char *name = opt_string(nrhs, prhs, 1);
        bass_port *port = NULL;
        bass_result r = bass_port_open(name ? name : "default", &port);
        if (name) mxFree(name);
        check("Open", r);
        plhs[0] = u64_scalar(handle_new(PORT, port));
    } else if (!strcmp(cmd, "Close")) {
        struct slot *sl = handle_arg(nrhs, prhs, 1, PORT);
        bass_result r = bass_port_close((bass_port *)sl->ptr);
        *sl = (struct slot){FREE, 0, NULL};
        check("Close", r);
    } else if (!strcmp(cmd, "Info")) {
        bass_port_info info;
        check("Info", bass_port_get_info(port_arg(nrhs, prhs, 1), &info));
        plhs[0] = info_struct(&info);
    } else if (!strcmp(cmd, "ChunkInfo")) {
        if (nrhs < 3) usage("ChunkInfo needs a port handle and a frame index");
        uint64_t frame = arg_u64(prhs[2], "frame");
        bass_chunk_info ci;
        bass_chunk_ext ce;
        const bass_port *p = port_arg(nrhs, prhs, 1);
        check("ChunkInfo", bass_port_chunk_info(p, frame, &ci));
        check("ChunkInfo", bass_port_chunk_ext(p, frame, &ce));
        plhs[0] = chunk_struct(&ci, &ce);
    } else if (!strcmp(cmd, "GetAudioData")) {
        cmd_get_audio_data(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "GetAudioDataMulti")) {
        cmd_get_audio_data_multi(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "Wait")) {
        cmd_wait(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "WriterCreate")) {
        if (nrhs < 7) usage("WriterCreate needs name, device, rate, nfpc, ncop, channels");
        uint32_t rate = arg_u32(prhs[3], "rate"), nfpc = arg_u32(prhs[4], "nfpc");
        uint32_t ncop = arg_u32(prhs[5], "ncop"), channels = arg_u32(prhs[6], "channels");
        char *name = opt_string(nrhs, prhs, 1), *device = opt_string(nrhs, prhs, 2);
        bass_writer *w = NULL;
        bass_result r = bass_writer_create(name, device, rate, nfpc, ncop, channels, &w);
        if (name) mxFree(name);
        if (device) mxFree(device);
        check("WriterCreate", r);
        plhs[0] = u64_scalar(handle_new(WRITER, w));
    } else if (!strcmp(cmd, "Publish")) {
        if (nrhs < 3 || !mxIsInt32(prhs[2])) usage("Publish needs a writer and int32 interleaved samples");
        uint64_t lfi = 0;
        check("Publish", bass_writer_publish_interleaved(writer_arg(nrhs, prhs, 1), (const int32_t *)mxGetData(prhs[2]),
                                                         mxGetNumberOfElements(prhs[2]), NULL, &lfi));
        if (nlhs > 0) plhs[0] = u64_scalar(lfi);
    } else if (!strcmp(cmd, "WriterClose")) {
        if (nrhs < 2) usage("WriterClose needs a writer");
        struct slot *sl = handle_arg(nrhs, prhs, 1, WRITER);
        bass_result r = bass_writer_close((bass_writer *)sl->ptr);
        *sl = (struct slot){FREE, 0, NULL};
        check("WriterClose", r);
    } else {
        mexErrMsgIdAndTxt("bass:usage", "bass_mex: unknown command '%s'", cmd);
    }
}
