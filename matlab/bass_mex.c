/* bass_mex: the Matlab / GNU Octave MEX gateway of bass, in C over include/bass.h only.
 *
 *   v                      = bass_mex('Version')
 *   epoch                  = bass_mex('Acquire', device, sampleRate, nFramesPerChunk, nChunksOnPort [, channels [, broker]])
 *                            bass_mex('Stop' [, broker])
 *   s                      = bass_mex('Status' [, broker])            struct
 *   devices                = bass_mex('ListDevices' [, broker])       n x 2 cell {name, description}; printed if nargout = 0
 *   h                      = bass_mex('Open' [, name])                 port handle (uint64)
 *                            bass_mex('Close', h)
 *   info                   = bass_mex('Info', h)                       struct
 *   [l, r, nfr, n, loss]   = bass_mex('GetAudioData', h, N, nfr [, noLoss])
 *   [x, nfr, n, loss]      = bass_mex('GetAudioDataMulti', h, N, nfr)   x: n x channels int32
 *   lfi                    = bass_mex('Wait', h, frame [, timeoutSeconds])
 *   w                      = bass_mex('WriterCreate', name, device, channels, rate, nfpc, ncop)
 *   lfi                    = bass_mex('Publish', w, int32 interleaved samples)
 *                            bass_mex('WriterClose', w)
 *
 * GetAudioData is the formal getAudioData: l and r are int32 columns of n frames, nfr (uint64)
 * the next frame to read, loss the frames that left the window first. With noLoss true, a
 * loss raises bass:lost instead. Wait blocks until `frame` is published, in slices of 100 ms
 * so that Ctrl-C returns to the prompt (error bass:interrupted); timeoutSeconds Inf (the
 * default) waits forever.
 *
 * Errors carry identifiers bass:<code> (bass:noPort, bass:noBroker, bass:timeout,
 * bass:stopped, bass:device, bass:restarted, bass:writerGone, bass:lost, ...) and the
 * library's message. Build: `mkoctfile --mex` (Octave) or `mex` (Matlab), see matlab/README.md.
 */
#include <math.h>
#include <stdbool.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "bass.h"
#include "mex.h"

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

static const char *const IDS[] = {
    "bass:ok",          "bass:nullArgument", "bass:invalidArgument", "bass:invalidHandle", "bass:noPort",
    "bass:notReady",    "bass:badMagic",     "bass:incompatible",    "bass:corrupt",       "bass:io",
    "bass:timeout",     "bass:stopped",      "bass:device",          "bass:restarted",     "bass:writerGone",
    "bass:lost",        "bass:notYet",       "bass:interrupted",     "bass:broker",        "bass:noBroker",
    "bass:protocol",    "bass:panic",        "bass:bufferTooSmall",
};

static const char *error_id(bass_result r) {
    unsigned i = (unsigned)r;
    return i < sizeof IDS / sizeof IDS[0] ? IDS[i] : "bass:unknown";
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

/* A non-negative integer argument given as any numeric class (uint64 exactly). */
static uint64_t arg_u64(const mxArray *a, const char *what) {
    if (!mxIsNumeric(a) || mxIsComplex(a) || mxGetNumberOfElements(a) != 1)
        mexErrMsgIdAndTxt("bass:usage", "bass_mex: %s must be a real scalar", what);
    if (mxIsUint64(a)) return *(const uint64_t *)mxGetData(a);
    if (mxIsInt64(a)) {
        int64_t v = *(const int64_t *)mxGetData(a);
        if (v < 0) mexErrMsgIdAndTxt("bass:usage", "bass_mex: %s must be >= 0", what);
        return (uint64_t)v;
    }
    double d = mxGetScalar(a);
    if (!(d >= 0) || d != floor(d) || d >= 18446744073709551616.0)
        mexErrMsgIdAndTxt("bass:usage", "bass_mex: %s must be a non-negative integer", what);
    return (uint64_t)d;
}

static mxArray *u64_scalar(uint64_t v) {
    mxArray *m = mxCreateNumericMatrix(1, 1, mxUINT64_CLASS, mxREAL);
    *(uint64_t *)mxGetData(m) = v;
    return m;
}

static bass_port *port_arg(int nrhs, const mxArray *prhs[], int i) {
    if (i >= nrhs) usage("missing port handle");
    return (bass_port *)(uintptr_t)arg_u64(prhs[i], "port handle");
}

static const char *const STATE_NAMES[] = {"idle", "capturing", "stopped", "error", "superseded"};

static const char *state_name(uint32_t s) { return s < 5 ? STATE_NAMES[s] : "unknown"; }

static mxArray *info_struct(const bass_port_info *i) {
    static const char *fields[] = {"channels", "sampleRate", "nFramesPerChunk", "nChunksOnPort", "nFramesOnPort",
                                   "lastFrameIndex", "epoch", "state", "errorCode", "xruns", "gapFrames",
                                   "chunksPublished", "rateEstimateHz", "writerPid", "writerAlive", "device",
                                   "message"};
    mxArray *s = mxCreateStructMatrix(1, 1, sizeof fields / sizeof fields[0], fields);
    mxSetField(s, 0, "channels", mxCreateDoubleScalar(i->channels));
    mxSetField(s, 0, "sampleRate", mxCreateDoubleScalar(i->sample_rate));
    mxSetField(s, 0, "nFramesPerChunk", mxCreateDoubleScalar(i->frames_per_chunk));
    mxSetField(s, 0, "nChunksOnPort", mxCreateDoubleScalar(i->chunks_on_port));
    mxSetField(s, 0, "nFramesOnPort", mxCreateDoubleScalar((double)i->frames_on_port));
    mxSetField(s, 0, "lastFrameIndex", u64_scalar(i->last_frame_index));
    mxSetField(s, 0, "epoch", u64_scalar(i->epoch));
    mxSetField(s, 0, "state", mxCreateString(state_name(i->state)));
    mxSetField(s, 0, "errorCode", mxCreateDoubleScalar(i->error_code));
    mxSetField(s, 0, "xruns", u64_scalar(i->xruns));
    mxSetField(s, 0, "gapFrames", u64_scalar(i->gap_frames));
    mxSetField(s, 0, "chunksPublished", u64_scalar(i->chunks_published));
    mxSetField(s, 0, "rateEstimateHz", mxCreateDoubleScalar(i->rate_estimate_hz));
    mxSetField(s, 0, "writerPid", mxCreateDoubleScalar(i->writer_pid));
    mxSetField(s, 0, "writerAlive", mxCreateLogicalScalar(i->writer_alive != 0));
    mxSetField(s, 0, "device", mxCreateString(i->device));
    mxSetField(s, 0, "message", mxCreateString(i->message));
    return s;
}

static mxArray *status_struct(const bass_broker_status *st) {
    static const char *fields[] = {"state",  "errorCode", "sampleRate", "nFramesPerChunk", "nChunksOnPort",
                                   "channels", "epoch",   "lastFrameIndex", "xruns",       "gapFrames",
                                   "rateEstimateHz", "device", "message"};
    mxArray *s = mxCreateStructMatrix(1, 1, sizeof fields / sizeof fields[0], fields);
    mxSetField(s, 0, "state", mxCreateString(state_name(st->state)));
    mxSetField(s, 0, "errorCode", mxCreateDoubleScalar(st->error_code));
    mxSetField(s, 0, "sampleRate", mxCreateDoubleScalar(st->sample_rate));
    mxSetField(s, 0, "nFramesPerChunk", mxCreateDoubleScalar(st->frames_per_chunk));
    mxSetField(s, 0, "nChunksOnPort", mxCreateDoubleScalar(st->chunks_on_port));
    mxSetField(s, 0, "channels", mxCreateDoubleScalar(st->channels));
    mxSetField(s, 0, "epoch", u64_scalar(st->epoch));
    mxSetField(s, 0, "lastFrameIndex", u64_scalar(st->last_frame_index));
    mxSetField(s, 0, "xruns", u64_scalar(st->xruns));
    mxSetField(s, 0, "gapFrames", u64_scalar(st->gap_frames));
    mxSetField(s, 0, "rateEstimateHz", mxCreateDoubleScalar(st->rate_estimate_hz));
    mxSetField(s, 0, "device", mxCreateString(st->device));
    mxSetField(s, 0, "message", mxCreateString(st->message));
    return s;
}

static void cmd_acquire(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    if (nrhs < 5) usage("Acquire needs device, sampleRate, nFramesPerChunk, nChunksOnPort");
    char *device = opt_string(nrhs, prhs, 1);
    if (!device) usage("Acquire: device must be a non-empty string");
    uint32_t rate = (uint32_t)arg_u64(prhs[2], "sampleRate");
    uint32_t nfpc = (uint32_t)arg_u64(prhs[3], "nFramesPerChunk");
    uint32_t ncop = (uint32_t)arg_u64(prhs[4], "nChunksOnPort");
    uint32_t channels = nrhs > 5 && !mxIsEmpty(prhs[5]) ? (uint32_t)arg_u64(prhs[5], "channels") : 0;
    char *broker = opt_string(nrhs, prhs, 6);
    uint64_t epoch = 0;
    bass_result r = bass_acquire(broker, device, rate, nfpc, ncop, channels, &epoch);
    mxFree(device);
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
    bass_port *port = port_arg(nrhs, prhs, 1);
    uint64_t n_req = arg_u64(prhs[2], "N");
    uint64_t nfr = arg_u64(prhs[3], "nfr");
    int no_loss = nrhs > 4 && (mxIsLogicalScalarTrue(prhs[4]) || (mxIsNumeric(prhs[4]) && mxGetScalar(prhs[4]) != 0));
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
    bass_port *port = port_arg(nrhs, prhs, 1);
    uint64_t n_req = arg_u64(prhs[2], "N");
    uint64_t nfr = arg_u64(prhs[3], "nfr");
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

static void cmd_wait(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    if (nrhs < 3) usage("Wait needs a port handle and a frame index");
    bass_port *port = port_arg(nrhs, prhs, 1);
    uint64_t frame = arg_u64(prhs[2], "frame");
    double timeout = nrhs > 3 ? mxGetScalar(prhs[3]) : INFINITY;
    if (!(timeout >= 0)) usage("Wait: timeoutSeconds must be >= 0");
    double left_ms = timeout * 1000.0;
    uint64_t lfi = 0;
    for (;;) {
        uint32_t slice = left_ms < 100.0 ? (uint32_t)left_ms : 100u;
        bass_result r = bass_port_wait(port, frame, slice, &lfi);
        if (r == BASS_OK) break;
        if (r == BASS_ERR_INTERRUPTED || interrupt_pending())
            mexErrMsgIdAndTxt("bass:interrupted", "Wait: interrupted while waiting for frame %llu",
                              (unsigned long long)frame);
        if (r != BASS_ERR_TIMEOUT) fail("Wait", r);
        left_ms -= slice;
        if (left_ms <= 0) fail("Wait", r);
    }
    (void)nlhs;
    plhs[0] = u64_scalar(lfi);
}

void mexFunction(int nlhs, mxArray *plhs[], int nrhs, const mxArray *prhs[]) {
    if (nrhs < 1 || !mxIsChar(prhs[0])) usage("the first argument is a command, e.g. 'GetAudioData'");
    char cmd[32];
    if (mxGetString(prhs[0], cmd, sizeof cmd)) usage("unknown command");

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
        bass_result r = bass_status(broker, &st);
        if (broker) mxFree(broker);
        check("Status", r);
        plhs[0] = status_struct(&st);
    } else if (!strcmp(cmd, "ListDevices")) {
        cmd_list_devices(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "Open")) {
        char *name = opt_string(nrhs, prhs, 1);
        bass_port *port = NULL;
        bass_result r = bass_port_open(name ? name : "default", &port);
        if (name) mxFree(name);
        check("Open", r);
        plhs[0] = u64_scalar((uint64_t)(uintptr_t)port);
    } else if (!strcmp(cmd, "Close")) {
        check("Close", bass_port_close(port_arg(nrhs, prhs, 1)));
    } else if (!strcmp(cmd, "Info")) {
        bass_port_info info;
        check("Info", bass_port_get_info(port_arg(nrhs, prhs, 1), &info));
        plhs[0] = info_struct(&info);
    } else if (!strcmp(cmd, "GetAudioData")) {
        cmd_get_audio_data(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "GetAudioDataMulti")) {
        cmd_get_audio_data_multi(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "Wait")) {
        cmd_wait(nlhs, plhs, nrhs, prhs);
    } else if (!strcmp(cmd, "WriterCreate")) {
        if (nrhs < 7) usage("WriterCreate needs name, device, channels, rate, nfpc, ncop");
        char *name = opt_string(nrhs, prhs, 1), *device = opt_string(nrhs, prhs, 2);
        bass_writer *w = NULL;
        bass_result r = bass_writer_create(name, device, (uint32_t)arg_u64(prhs[3], "channels"),
                                           (uint32_t)arg_u64(prhs[4], "rate"), (uint32_t)arg_u64(prhs[5], "nfpc"),
                                           (uint32_t)arg_u64(prhs[6], "ncop"), &w);
        if (name) mxFree(name);
        if (device) mxFree(device);
        check("WriterCreate", r);
        plhs[0] = u64_scalar((uint64_t)(uintptr_t)w);
    } else if (!strcmp(cmd, "Publish")) {
        if (nrhs < 3 || !mxIsInt32(prhs[2])) usage("Publish needs a writer and int32 interleaved samples");
        uint64_t lfi = 0;
        check("Publish", bass_writer_publish_interleaved((bass_writer *)(uintptr_t)arg_u64(prhs[1], "writer"),
                                                         (const int32_t *)mxGetData(prhs[2]),
                                                         mxGetNumberOfElements(prhs[2]), NULL, &lfi));
        if (nlhs > 0) plhs[0] = u64_scalar(lfi);
    } else if (!strcmp(cmd, "WriterClose")) {
        if (nrhs < 2) usage("WriterClose needs a writer");
        check("WriterClose", bass_writer_close((bass_writer *)(uintptr_t)arg_u64(prhs[1], "writer")));
    } else {
        mexErrMsgIdAndTxt("bass:usage", "bass_mex: unknown command '%s'", cmd);
    }
}
