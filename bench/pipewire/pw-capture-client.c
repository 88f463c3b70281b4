/* pw-capture-client: one PipeWire capture client of the bench's PipeWire comparison
 * (bench/src/pipewire.rs; docs/performance.md, "PipeWire").
 *
 * A pw_stream (PW_DIRECTION_INPUT, 2 channels S32 at 48 kHz) connected with
 * AUTOCONNECT | MAP_BUFFERS | RT_PROCESS, so that its process callback runs on the client's
 * data thread, as a JACK or a low-latency PipeWire client's does. There is no session manager:
 * the stream asks to be scheduled without links (`node.always-process`, `node.want-driver`),
 * and the daemon adds it to the only driver, the Dummy-Driver.
 *
 * Per cycle the callback records, first thing, CLOCK_MONOTONIC (entered), then the cycle's
 * clock from pw_stream_get_time_n(): `now` is the driver's clock.nsec, which for the
 * Dummy-Driver is the target time of its timerfd (the time the cycle was due), and `ticks`
 * its position in frames (a jump of more than one quantum = missed cycles). It dequeues the
 * buffer, reads the first sample and queues it back; nothing else (no allocation, no I/O).
 *
 * Protocol with the bench (stdout): `ready` once the stream is streaming; on SIGTERM or SIGINT
 * one line per cycle `ENTERED_NS TARGET_NS TICKS`, then `cycles=N dropped=M` (M cycles did not
 * fit in the table).
 *
 * Usage: pw-capture-client NODE_NAME QUANTUM RATE
 */
#include <inttypes.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include <pipewire/pipewire.h>
#include <spa/param/audio/format-utils.h>
#include <spa/utils/result.h>

#define MAX_CYCLES (1u << 18)

struct cycle {
	uint64_t entered;
	uint64_t target;
	uint64_t ticks;
};

struct data {
	struct pw_main_loop *loop;
	struct pw_stream *stream;
	struct cycle *cycles;
	uint32_t n;
	uint64_t dropped;
	int said_ready;
	volatile int32_t sink;
};

static uint64_t mono_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

static void on_process(void *userdata)
{
	struct data *d = userdata;
	uint64_t entered = mono_ns();
	struct pw_time t;
	struct pw_buffer *b;

	if (pw_stream_get_time_n(d->stream, &t, sizeof(t)) < 0)
		t.now = 0, t.ticks = 0;
	b = pw_stream_dequeue_buffer(d->stream);
	if (b != NULL) {
		struct spa_buffer *buf = b->buffer;
		if (buf->n_datas > 0 && buf->datas[0].data != NULL && buf->datas[0].chunk->size >= 4)
			d->sink = *(const int32_t *)buf->datas[0].data;
		pw_stream_queue_buffer(d->stream, b);
	}
	if (d->n < MAX_CYCLES) {
		d->cycles[d->n].entered = entered;
		d->cycles[d->n].target = (uint64_t)t.now;
		d->cycles[d->n].ticks = t.ticks;
		d->n++;
	} else {
		d->dropped++;
	}
}

static void on_state_changed(void *userdata, enum pw_stream_state old, enum pw_stream_state state,
			     const char *error)
{
	struct data *d = userdata;
	(void)old;
	if (state == PW_STREAM_STATE_STREAMING && !d->said_ready) {
		d->said_ready = 1;
		printf("ready\n");
		fflush(stdout);
	} else if (state == PW_STREAM_STATE_ERROR) {
		fprintf(stderr, "pw-capture-client: stream error: %s\n", error ? error : "?");
		pw_main_loop_quit(d->loop);
	}
}

static const struct pw_stream_events stream_events = {
	PW_VERSION_STREAM_EVENTS,
	.state_changed = on_state_changed,
	.process = on_process,
};

static void on_quit(void *userdata, int signal_number)
{
	struct data *d = userdata;
	(void)signal_number;
	pw_main_loop_quit(d->loop);
}

int main(int argc, char *argv[])
{
	struct data d = { 0 };
	const struct spa_pod *params[1];
	uint8_t buffer[1024];
	struct spa_pod_builder b = SPA_POD_BUILDER_INIT(buffer, sizeof(buffer));
	struct pw_properties *props;
	const char *name, *quantum, *rate;
	uint32_t i;
	int r;

	if (argc != 4) {
		fprintf(stderr, "usage: %s NODE_NAME QUANTUM RATE\n", argv[0]);
		return 2;
	}
	name = argv[1];
	quantum = argv[2];
	rate = argv[3];
	d.cycles = calloc(MAX_CYCLES, sizeof(*d.cycles));
	if (d.cycles == NULL)
		return 1;

	pw_init(&argc, &argv);
	d.loop = pw_main_loop_new(NULL);
	if (d.loop == NULL) {
		fprintf(stderr, "pw-capture-client: no main loop\n");
		return 1;
	}
	pw_loop_add_signal(pw_main_loop_get_loop(d.loop), SIGINT, on_quit, &d);
	pw_loop_add_signal(pw_main_loop_get_loop(d.loop), SIGTERM, on_quit, &d);

	props = pw_properties_new(PW_KEY_MEDIA_TYPE, "Audio", PW_KEY_MEDIA_CATEGORY, "Capture",
				  PW_KEY_MEDIA_ROLE, "Production", PW_KEY_NODE_NAME, name,
				  PW_KEY_NODE_ALWAYS_PROCESS, "true", PW_KEY_NODE_WANT_DRIVER, "true",
				  /* What a session manager would do: one port per channel. */
				  "adapter.auto-port-config",
				  "{ mode = dsp monitor = false control = false position = preserve }", NULL);
	pw_properties_setf(props, PW_KEY_NODE_LATENCY, "%s/%s", quantum, rate);
	pw_properties_setf(props, PW_KEY_NODE_RATE, "1/%s", rate);
	d.stream = pw_stream_new_simple(pw_main_loop_get_loop(d.loop), name, props, &stream_events, &d);
	if (d.stream == NULL) {
		fprintf(stderr, "pw-capture-client: pw_stream_new_simple failed\n");
		return 1;
	}
	params[0] = spa_format_audio_raw_build(&b, SPA_PARAM_EnumFormat,
					       &SPA_AUDIO_INFO_RAW_INIT(.format = SPA_AUDIO_FORMAT_S32,
									.channels = 2,
									.rate = (uint32_t)atoi(rate)));
	r = pw_stream_connect(d.stream, PW_DIRECTION_INPUT, PW_ID_ANY,
			      PW_STREAM_FLAG_AUTOCONNECT | PW_STREAM_FLAG_MAP_BUFFERS |
				      PW_STREAM_FLAG_RT_PROCESS,
			      params, 1);
	if (r < 0) {
		fprintf(stderr, "pw-capture-client: pw_stream_connect: %s\n", spa_strerror(r));
		return 1;
	}
	pw_main_loop_run(d.loop);
	pw_stream_disconnect(d.stream);
	for (i = 0; i < d.n; i++)
		printf("%" PRIu64 " %" PRIu64 " %" PRIu64 "\n", d.cycles[i].entered, d.cycles[i].target,
		       d.cycles[i].ticks);
	printf("cycles=%" PRIu32 " dropped=%" PRIu64 "\n", d.n, d.dropped);
	fflush(stdout);
	pw_stream_destroy(d.stream);
	pw_main_loop_destroy(d.loop);
	pw_deinit();
	free(d.cycles);
	return 0;
}
