/* bass_mex_tables.h: the MEX gateway's tables of include/bass.h facts — the error id of every
 * result code, the Matlab field of every member of the structs it returns, the name of every
 * chunk flag. Included once, by bass_mex.c (after bass.h and mex.h). A C compiler cannot
 * check these for completeness; tests/clients/test_mex_drift.py fails when the header gains a
 * code, a member or a flag that is missing here. */
#ifndef BASS_MEX_TABLES_H
#define BASS_MEX_TABLES_H

#include <stddef.h>
#include <stdint.h>

/* The error identifier of every result code of bass.h, in the header's order.
 * tests/clients/test_mex_drift.py fails when a code of the header is missing here. */
static const char *const IDS[] = {
    [BASS_OK] = "bass:ok",
    [BASS_ERR_NULL_ARGUMENT] = "bass:nullArgument",
    [BASS_ERR_INVALID_ARGUMENT] = "bass:invalidArgument",
    [BASS_ERR_INVALID_HANDLE] = "bass:invalidHandle",
    [BASS_ERR_NOT_FOUND] = "bass:noPort",
    [BASS_ERR_NOT_READY] = "bass:notReady",
    [BASS_ERR_BAD_MAGIC] = "bass:badMagic",
    [BASS_ERR_INCOMPATIBLE] = "bass:incompatible",
    [BASS_ERR_CORRUPT] = "bass:corrupt",
    [BASS_ERR_IO] = "bass:io",
    [BASS_ERR_TIMEOUT] = "bass:timeout",
    [BASS_ERR_STOPPED] = "bass:stopped",
    [BASS_ERR_DEVICE] = "bass:device",
    [BASS_ERR_RESTARTED] = "bass:restarted",
    [BASS_ERR_WRITER_GONE] = "bass:writerGone",
    [BASS_ERR_FRAME_LOST] = "bass:lost",
    [BASS_ERR_FRAME_NOT_YET] = "bass:notYet",
    [BASS_ERR_INTERRUPTED] = "bass:interrupted",
    [BASS_ERR_BROKER] = "bass:broker",
    [BASS_ERR_NO_BROKER] = "bass:noBroker",
    [BASS_ERR_PROTOCOL] = "bass:protocol",
    [BASS_ERR_PANIC] = "bass:panic",
    [BASS_ERR_BUFFER_TOO_SMALL] = "bass:bufferTooSmall",
    [BASS_ERR_WRONG_OWNER] = "bass:wrongOwner",
    [BASS_ERR_NEVER_READY] = "bass:neverReady",
};

/* How a C struct member becomes a Matlab value. */
enum value_kind {
    AS_DOUBLE_U32, /* uint32_t -> double */
    AS_DOUBLE_U64, /* uint64_t -> double (sizes, exact below 2^53) */
    AS_UINT64,     /* uint64_t -> uint64 (frame indices, counters, nanoseconds) */
    AS_DOUBLE,     /* double -> double */
    AS_LOGICAL,    /* uint32_t 0/1 -> logical */
    AS_STATE,      /* uint32_t BASS_STATE_* -> its name */
    AS_TEXT,       /* NUL-terminated char array -> string */
};

/* One Matlab struct field: its name, the C member (offsetof) and how it is converted. */
struct field_map {
    const char *name;
    size_t offset;
    enum value_kind kind;
};

#define FIELD(type, matlab, member, kind) {matlab, offsetof(type, member), kind}

/* Every member of bass_port_info, in the header's order. tests/clients/test_mex_drift.py
 * fails when a member of the header is missing here. */
static const struct field_map INFO_FIELDS[] = {
    FIELD(bass_port_info, "channels", channels, AS_DOUBLE_U32),
    FIELD(bass_port_info, "sampleRate", sample_rate, AS_DOUBLE_U32),
    FIELD(bass_port_info, "nFramesPerChunk", frames_per_chunk, AS_DOUBLE_U32),
    FIELD(bass_port_info, "nChunksOnPort", chunks_on_port, AS_DOUBLE_U32),
    FIELD(bass_port_info, "nFramesOnPort", frames_on_port, AS_DOUBLE_U64),
    FIELD(bass_port_info, "lastFrameIndex", last_frame_index, AS_UINT64),
    FIELD(bass_port_info, "epoch", epoch, AS_UINT64),
    FIELD(bass_port_info, "state", state, AS_STATE),
    FIELD(bass_port_info, "errorCode", error_code, AS_DOUBLE_U32),
    FIELD(bass_port_info, "xruns", xruns, AS_UINT64),
    FIELD(bass_port_info, "gapFrames", gap_frames, AS_UINT64),
    FIELD(bass_port_info, "chunksPublished", chunks_published, AS_UINT64),
    FIELD(bass_port_info, "rateEstimateHz", rate_estimate_hz, AS_DOUBLE),
    FIELD(bass_port_info, "writerPid", writer_pid, AS_DOUBLE_U32),
    FIELD(bass_port_info, "writerAlive", writer_alive, AS_LOGICAL),
    FIELD(bass_port_info, "startedMonoNs", started_mono_ns, AS_UINT64),
    FIELD(bass_port_info, "heartbeatMonoNs", heartbeat_mono_ns, AS_UINT64),
    FIELD(bass_port_info, "device", device, AS_TEXT),
    FIELD(bass_port_info, "message", message, AS_TEXT),
    FIELD(bass_port_info, "lostUpstreamFrames", lost_upstream_frames, AS_UINT64),
};

/* Every member of bass_broker_status, in the header's order (checked like INFO_FIELDS). */
static const struct field_map STATUS_FIELDS[] = {
    FIELD(bass_broker_status, "state", state, AS_STATE),
    FIELD(bass_broker_status, "errorCode", error_code, AS_DOUBLE_U32),
    FIELD(bass_broker_status, "sampleRate", sample_rate, AS_DOUBLE_U32),
    FIELD(bass_broker_status, "nFramesPerChunk", frames_per_chunk, AS_DOUBLE_U32),
    FIELD(bass_broker_status, "nChunksOnPort", chunks_on_port, AS_DOUBLE_U32),
    FIELD(bass_broker_status, "channels", channels, AS_DOUBLE_U32),
    FIELD(bass_broker_status, "epoch", epoch, AS_UINT64),
    FIELD(bass_broker_status, "lastFrameIndex", last_frame_index, AS_UINT64),
    FIELD(bass_broker_status, "xruns", xruns, AS_UINT64),
    FIELD(bass_broker_status, "gapFrames", gap_frames, AS_UINT64),
    FIELD(bass_broker_status, "rateEstimateHz", rate_estimate_hz, AS_DOUBLE),
    FIELD(bass_broker_status, "device", device, AS_TEXT),
    FIELD(bass_broker_status, "message", message, AS_TEXT),
};

/* Every member of bass_chunk_info, in the header's order (checked like INFO_FIELDS). */
static const struct field_map CHUNK_FIELDS[] = {
    FIELD(bass_chunk_info, "firstFrame", first_frame, AS_UINT64),
    FIELD(bass_chunk_info, "monoNs", mono_ns, AS_UINT64),
    FIELD(bass_chunk_info, "realtimeNs", realtime_ns, AS_UINT64),
    FIELD(bass_chunk_info, "frames", frames, AS_DOUBLE_U32),
    FIELD(bass_chunk_info, "flags", flags, AS_DOUBLE_U32),
};

/* Every BASS_CHUNK_* flag of the header, in its order: ChunkInfo adds one logical field
 * per flag (checked like INFO_FIELDS). */
static const struct {
    uint32_t bit;
    const char *name;
} CHUNK_FLAGS[] = {
    {BASS_CHUNK_GAP, "gap"},
    {BASS_CHUNK_DISCONTINUITY, "discontinuity"},
    {BASS_CHUNK_TIME_ESTIMATED, "timeEstimated"},
    {BASS_CHUNK_LATE, "late"},
};

#endif
