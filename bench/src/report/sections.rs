//! One section of performance.md per part of the bench.

use std::fmt::Write as _;

use crate::publish::Design;
use crate::stats::{fmt_ns, fmt_ratio, median, min_max, spread};

use super::Results;

fn gbs(v: &[f64]) -> String {
    spread(v, |x| format!("{x:.1}"))
}

pub(super) fn read_section(r: &Results, md: &mut String) {
    if r.read.is_empty() {
        return;
    }
    let _ = writeln!(md, "## 1. Read throughput: `bass_get_audio_data` vs memcpy\n");
    let _ = writeln!(
        md,
        "44.1 kHz stereo, a port holding 10.01 s, filled (the ring has wrapped). Each timing sample copies ~32 MB; \
         the C ABI call and a plain `memcpy` of exactly the same ring segments into the same buffers \
         alternate in the same sample, in the order C ABI, memcpy, memcpy, C ABI over the two halves of its blocks (so \
         that neither always runs right after the other), then the Rust call. *Hot*: the newest block is read again and again (source in L1/L2). \
         *Streaming*: successive blocks through the 10 s window, as a reader consuming the stream, after one untimed \
         pass over them (the 3.5 MB window then sits in the last-level cache for both sides, as one the writer has just \
         written does; before 2026-12-07 the side timed first paid for bringing it in, and that side was bass). GB/s = 10⁹ bytes/s; \
         median [min–max] of {} repetitions; ratio = memcpy time / `bass_get_audio_data` time.\n",
        r.read[0].ratio.len()
    );
    let _ = writeln!(md, "| block | bytes | per call | `bass_get_audio_data` GB/s | `Port::get_audio_data` GB/s | memcpy GB/s | **ratio (hot)** | streaming bass / memcpy GB/s | **ratio (streaming)** |");
    let _ = writeln!(md, "|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for x in &r.read {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | **{}** | {} / {} | **{}** |",
            x.label,
            x.bytes,
            fmt_ns(median(&x.ffi_call_ns)),
            gbs(&x.ffi_gbs),
            gbs(&x.rust_gbs),
            gbs(&x.memcpy_gbs),
            spread(&x.ratio, fmt_ratio),
            format_args!("{:.1}", median(&x.stream_ffi_gbs)),
            format_args!("{:.1}", median(&x.stream_memcpy_gbs)),
            spread(&x.stream_ratio, fmt_ratio),
        );
    }
    copy_paths_table(r, md);
    if let Some(c) = &r.copy_loops {
        let rings = |r: &[(bassport::ring::CopyPath, Vec<f64>)], memcpy: &[f64]| {
            r.iter()
                .map(|(p, v)| {
                    format!(
                        "`{}` {} GB/s = {} of memcpy",
                        p.name(),
                        gbs(v),
                        fmt_ratio(median(v) / median(memcpy))
                    )
                })
                .collect::<Vec<_>>()
                .join("; ")
        };
        let _ = writeln!(
            md,
            "\nCopy loops alone, 64 KiB hot, same run, the destination {} B past the source modulo 4 KiB: memcpy {} GB/s; \
             the reader's ring copy (`ChannelRing::copy_to`) by path: {}; a loop of Relaxed `AtomicU64` loads (the \
             portable path of other architectures) {} GB/s = {} of memcpy. The same with the destination {} B past the \
             source modulo 4 KiB (4 KiB aliasing, where a fast-string `rep movsb` — glibc's memcpy from ~2 KiB up on \
             CPUs with ERMS — slows down on some CPUs): memcpy {} GB/s; {}.\n",
            crate::read::FAR,
            gbs(&c.memcpy),
            rings(&c.ring, &c.memcpy),
            gbs(&c.atomic64),
            fmt_ratio(median(&c.atomic64) / median(&c.memcpy)),
            crate::read::ALIASED,
            gbs(&c.aliased_memcpy),
            rings(&c.aliased_ring, &c.aliased_memcpy),
        );
    }
    if let Some(i) = &r.info_cost {
        let _ = writeln!(
            md,
            "`bass_port_get_info` per call, same run: {} ns, against {} ns for `bass_get_audio_data` of one 441-frame \
             chunk ({} of it); whether the writer lives comes from a pidfd opened once per writer. The /proc read it \
             made on every call before (open, read, parse `/proc/PID/stat`) costs {} ns.\n",
            spread(&i.info_ns, |v| format!("{v:.0}")),
            spread(&i.read_chunk_ns, |v| format!("{v:.0}")),
            fmt_ratio(median(&i.info_ns) / median(&i.read_chunk_ns)),
            spread(&i.proc_ns, |v| format!("{v:.0}")),
        );
        let (ffi, rust) = (median(&i.ffi_one_ns), median(&i.rust_one_ns));
        let _ = writeln!(
            md,
            "The per-call cost, same run: `bass_get_audio_data` of one frame {} ns, `Port::get_audio_data` of one frame \
             {} ns. The difference, {:.0} ns, is the C ABI layer (the handle's registry lookup and `Arc` clone, the \
             argument checks, the panic boundary); the rest is the read itself (the Acquire load, the formal algorithm, \
             the fence and the intent re-check, the copy of two samples). At 64 KiB a call moves ~1.5 µs of bytes, \
             so this cost is ~{} of it.\n",
            spread(&i.ffi_one_ns, |v| format!("{v:.0}")),
            spread(&i.rust_one_ns, |v| format!("{v:.0}")),
            ffi - rust,
            fmt_ratio(ffi / 1500.0),
        );
    }
    let _ = writeln!(md, "![read throughput](perf-read.png)\n");
}

/// Part 1's blocks of at least 64 KiB by copy path, measured interleaved in the same run, and
/// the per-call cost each path leaves (the 1 ms block's time beyond its bytes at memcpy speed).
fn copy_paths_table(r: &Results, md: &mut String) {
    let Some(runs) = &r.read_paths else { return };
    if runs.by_path.len() < 2 {
        return;
    }
    let _ = writeln!(
        md,
        "\nThe copy paths of this CPU, interleaved in the same repetitions (the table above is the chosen path, {}):\n",
        runs.chosen.map_or("none", |p| p.name())
    );
    let _ = writeln!(md, "| path | block | ratio (hot) | ratio (streaming) |");
    let _ = writeln!(md, "|---|---|---:|---:|");
    for (path, rows) in &runs.by_path {
        for x in rows.iter().filter(|x| x.bytes >= 65536) {
            let _ = writeln!(
                md,
                "| `{}` | {} | {} | {} |",
                path.name(),
                x.label,
                spread(&x.ratio, fmt_ratio),
                spread(&x.stream_ratio, fmt_ratio)
            );
        }
    }
}

pub(super) fn publish_section(r: &Results, md: &mut String) {
    let Some(p) = &r.publish else { return };
    let _ = writeln!(md, "## 2. Publish cost vs window size and readers, vs the original design\n");
    let _ = writeln!(
        md,
        "44.1 kHz stereo, 2205-frame chunks (the seed's Acquire defaults); the window is filled first. A chunk is \
         published every {:.0} ms; reader *processes* are blocked in a wait and read every chunk. **CPU** = CPU time of \
         the writer thread inside the publish call (`CLOCK_THREAD_CPUTIME_ID`, minus the median cost of reading that clock); **wall** = elapsed time of the call \
         (includes being preempted by the readers it woke, and, for the original design, waiting for the port lock). \
         *Original*: the model of the seed's port (`bench/src/original.rs`): both arrays memmoved by one chunk for every \
         chunk, readers copy the whole port under a process-shared rwlock, then run getAudioData on their copy. \
         Median [min–max] of {} repetitions (each the median of up to 150 chunks); *read* = one reader's time for one read.\n",
        p.period_ms,
        p.cells.first().map(|c| c.publish_ns.len()).unwrap_or(0)
    );
    let _ = writeln!(md, "| window | readers | ring CPU | ring wall | ring read | original CPU | original wall | original read | **original / ring (CPU)** | original / ring (wall) |");
    let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &(w, _) in crate::publish::WINDOWS {
        for &k in crate::publish::READERS {
            let (Some(a), Some(b)) = (p.cell(Design::Ring, w, k), p.cell(Design::Original, w, k)) else {
                continue;
            };
            let ratio: Vec<f64> = b.publish_ns.iter().zip(&a.publish_ns).map(|(x, y)| x / y).collect();
            let _ = writeln!(
                md,
                "| {w} s | {k} | {} | {} | {} | {} | {} | {} | **{}** | {} |",
                spread(&a.publish_ns, fmt_ns),
                fmt_ns(median(&a.wall_ns)),
                if k == 0 { "–".into() } else { fmt_ns(median(&a.read_ns)) },
                spread(&b.publish_ns, fmt_ns),
                fmt_ns(median(&b.wall_ns)),
                if k == 0 { "–".into() } else { fmt_ns(median(&b.read_ns)) },
                spread(&ratio, fmt_ratio),
                fmt_ratio(median(&b.wall_ns) / median(&a.wall_ns)),
            );
        }
    }
    if !p.sweep.is_empty() {
        let _ = writeln!(md, "\nChunk size at a 10 s window (1 reader, same pacing): the original moves the whole window per chunk, the ring one chunk, so the gain grows with nCOP = window / chunk.\n");
        let _ = writeln!(md, "| chunk (frames) | nCOP | ring CPU | original CPU | **original / ring** |");
        let _ = writeln!(md, "|---:|---:|---:|---:|---:|");
        for x in &p.sweep {
            let ratio: Vec<f64> = x.orig_ns.iter().zip(&x.ring_ns).map(|(a, b)| a / b).collect();
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | **{}** |",
                x.frames_per_chunk,
                441_000u32.div_ceil(x.frames_per_chunk),
                spread(&x.ring_ns, fmt_ns),
                spread(&x.orig_ns, fmt_ns),
                spread(&ratio, fmt_ratio)
            );
        }
    }
    let b = &p.breakdown;
    let _ = writeln!(
        md,
        "\nWhere a ring publish goes (10 s window, no reader, back to back, caches warm; CPU per chunk): \
         `Writer::publish` {}; `Ring::publish` alone on a heap window {}; one `FUTEX_WAKE` with no waiter {}; \
         the two clock reads {}; a plain memcpy of the chunk's bytes {}.\n",
        fmt_ns(b.writer_publish),
        fmt_ns(b.ring_publish),
        fmt_ns(b.futex_wake),
        fmt_ns(b.clocks),
        fmt_ns(b.memcpy_chunk)
    );
    let _ = writeln!(md, "![publish cost](perf-publish.png)\n");
}

fn dist_row(md: &mut String, name: &str, d: &crate::wake::Dist, raw: f64) {
    let (lo, hi) = min_max(&d.rep_medians);
    let _ = writeln!(
        md,
        "| {name} | {} | {} | {} | {} | {}–{} | {} |",
        d.all.len(),
        fmt_ns(d.median()),
        fmt_ns(d.p99()),
        fmt_ns(d.max()),
        fmt_ns(lo),
        fmt_ns(hi),
        fmt_ratio(d.median() / raw)
    );
}

/// Callback streams: chunk published → block callback entered, against the
/// `Port::wait` readers and the raw futex interleaved with them in the same run.
fn stream_table(w: &crate::wake::WakeResults, md: &mut String) {
    if w.stream.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "Callback streams (`bassport::stream::Stream`, one chunk per block, from the live edge): chunk published \
         (its `mono_ns`, which the block carries) → block callback entered, interleaved publish by publish with the \
         `Port::wait` readers (*blocking*) and the raw futex (1 reader: the ping-pong; 8 and 64: one FUTEX_WAKE of \
         that many waiters), every reader counted. The callback is entered once its block is copied out, so the \
         blocking readers' *data in hand* (after `get_audio_data`) is the like-for-like of the last column. Ratios: median over repetitions of the per-repetition ratio.\n"
    );
    let _ = writeln!(
        md,
        "| readers | callback p50 | callback p99 | blocking p50 | blocking p99 | raw futex p50 | raw futex p99 | callback / blocking p50 (p99) | callback / raw p50 (p99) | blocking, data in hand p50 |"
    );
    let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let ratio =
        |m: &std::collections::BTreeMap<usize, Vec<f64>>, k: &usize| m.get(k).map_or(f64::NAN, |v| median(v));
    for (k, cb) in &w.stream {
        let blocking = w.bass.get(k).cloned().unwrap_or_default();
        let raw = if *k == 1 { w.raw.clone() } else { w.raw_n.get(k).cloned().unwrap_or_default() };
        let _ = writeln!(
            md,
            "| {k} | {} | {} | {} | {} | {} | {} | {} ({}) | {} ({}) | {} |",
            fmt_ns(cb.median()),
            fmt_ns(cb.p99()),
            fmt_ns(blocking.median()),
            fmt_ns(blocking.p99()),
            fmt_ns(raw.median()),
            fmt_ns(raw.p99()),
            fmt_ratio(ratio(&w.ratio_stream_blocking, k)),
            fmt_ratio(ratio(&w.ratio_stream_blocking_p99, k)),
            fmt_ratio(ratio(&w.ratio_stream_raw, k)),
            fmt_ratio(ratio(&w.ratio_stream_raw_p99, k)),
            fmt_ns(w.bass_data.get(k).map_or(f64::NAN, |d| d.median()))
        );
    }
    let _ = writeln!(md);
}

pub(super) fn wake_section(r: &Results, md: &mut String) {
    let Some(w) = &r.wake else { return };
    let _ = writeln!(md, "## 3. Wake latency: publish → blocked reader running\n");
    let _ = writeln!(
        md,
        "CLOCK_MONOTONIC from just before the publish (bass: the chunk's `mono_ns`, stamped right before \
         `Writer::publish`; raw futex: right before the store + `FUTEX_WAKE`) to the woken process running \
         (bass: `Port::wait` returned). Publishes are spaced by a random 3–6 ms so waiters are really asleep. \
         The raw futex ping-pong, the bass 1-reader case, the diagnostic bare-futex reader and the 1-reader case \
         on a sealed memfd port (`bassd --port-backing memfd`) are interleaved \
         publish by publish in the same run; so are, for 8 and then 64 readers, the readers of a file port, \
         the readers of a sealed memfd port and the raw futex waiters (all running at once; like a bass reader, \
         each raw waiter copies the block of its wake out of shared memory and takes the time again when it has it); {} publishes per configuration and repetition, {} repetitions, \
         samples pooled. *Last reader* = per publish, the latest of all readers. The polling client is the seed's \
         BASC `GetBlocks`, a periodic 250 ms task calling getAudioData (4 processes, 2205-frame chunks every 50 ms).\n",
        w.publishes,
        w.rep_count()
    );
    let raw = w.raw.median();
    let _ = writeln!(md, "| path | samples | median | p99 | max | repetition medians | median / raw futex |");
    let _ = writeln!(md, "|---|---:|---:|---:|---:|---:|---:|");
    dist_row(md, "raw futex ping-pong (2 processes)", &w.raw, raw);
    for (k, d) in &w.raw_n {
        dist_row(md, &format!("raw futex, one FUTEX_WAKE of {k} processes, each"), d, raw);
        if let Some(l) = w.raw_n_last.get(k) {
            dist_row(md, &format!("raw futex, {k} processes, last"), l, raw);
        }
    }
    dist_row(md, "bass writer → bare FUTEX_WAIT on the port (diagnostic)", &w.bass_raw_waiter, raw);
    for (k, d) in &w.bass {
        dist_row(md, &format!("**bass, {k} reader{}**, each reader", if *k == 1 { "" } else { "s" }), d, raw);
        if *k > 1 {
            if let Some(l) = w.bass_last.get(k) {
                dist_row(md, &format!("bass, {k} readers, last reader"), l, raw);
            }
        }
    }
    if let Some(d) = w.bass_data.get(&1) {
        dist_row(md, "bass, 1 reader, data in hand (after `get_audio_data`)", d, raw);
    }
    if !w.bass_memfd.all.is_empty() {
        dist_row(md, "bass, 1 reader of a sealed memfd port", &w.bass_memfd, raw);
    }
    for (k, d) in &w.bass_memfd_n {
        dist_row(md, &format!("bass, {k} readers of a sealed memfd port, each reader"), d, raw);
        if let Some(l) = w.bass_memfd_n_last.get(k) {
            dist_row(md, &format!("bass, {k} readers of a sealed memfd port, last reader"), l, raw);
        }
    }
    dist_row(md, "seed's 250 ms polling client", &w.poll, raw);
    let _ = writeln!(
        md,
        "\nPer-repetition ratio bass (1 reader) / raw futex: {}; the same on a sealed memfd port (interleaved \
         in the same run): {}.\n",
        spread(&w.ratio_1, fmt_ratio),
        spread(&w.ratio_memfd, fmt_ratio)
    );
    stream_table(w, md);
    let _ = writeln!(md, "Reader CPU per chunk (wake + `get_audio_data` + `chunk_info` + wait again, from `CLOCK_PROCESS_CPUTIME_ID`):");
    for (k, v) in &w.reader_cpu {
        let _ = write!(md, " {k} reader{}: {};", if *k == 1 { "" } else { "s" }, spread(v, fmt_ns));
    }
    for (k, v) in &w.reader_cpu_memfd {
        let _ = write!(md, " {k} readers of a sealed memfd port: {};", spread(v, fmt_ns));
    }
    for (k, v) in &w.raw_waiter_cpu {
        let _ = write!(
            md,
            " {k} raw futex waiters (wake, copy the block, record, wait again): {};",
            spread(v, fmt_ns)
        );
    }
    let _ = writeln!(md, " the bare-futex reader: {}.\n", spread(&w.bare_reader_cpu, fmt_ns));
    let _ = writeln!(md, "![wake latency](perf-wake.png)\n");
}

pub(super) fn e2e_section(r: &Results, md: &mut String) {
    let Some(e) = &r.e2e else {
        let _ = writeln!(md, "## 4. End to end through ALSA, and 5. CPU of bassd\n\nNot run.\n");
        return;
    };
    let _ = writeln!(md, "## 4. End to end through ALSA: jackd → ALSA jack PCM → bassd → reader\n");
    let _ = writeln!(
        md,
        "`jackd -d dummy -r 48000 -p PERIOD`; an ALSA configuration (`pcm.bassjack`: `plug` over `type jack` on \
         system:capture_1/2) passed with `ALSA_CONFIG_PATH`; `bassd --acquire bassjack --frames PERIOD` (its capture \
         thread SCHED_FIFO as by default); a bass reader in the benchmark process blocked in `Port::wait`, reading \
         every chunk. At the same time a direct JACK client in the benchmark process (libjack by dlopen) copies \
         each period in its process callback. Both delays are measured from the **start of the JACK cycle** that \
         made the data available (`jack_get_cycle_times`, converted to CLOCK_MONOTONIC; for bass the latest cycle \
         start before the reader woke): the JACK client's callback running, vs the bass reader having the chunk. \
         {:.0} s per period; one repetition.\n",
        e.seconds
    );
    if let Some(why) = &e.skipped {
        let _ = writeln!(md, "Skipped: {why}\n");
    }
    let _ = writeln!(md, "| JACK period = bass chunk | bass reader: median | p99 | chunks | direct JACK client: median | p99 | periods | **bass / JACK (median)** | reader − chunk timestamp (median) | bassd CPU | jackd CPU |");
    let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for x in &e.e2e {
        if x.bass.is_empty() {
            let _ = writeln!(
                md,
                "| {} | skipped: {} | | | | | | | | | |",
                x.period,
                x.skipped.as_deref().unwrap_or("no data")
            );
            continue;
        }
        let _ = writeln!(
            md,
            "| {} ({}) | {} | {} | {} | {} | {} | {} | **{}** | {} | {:.2} % | {:.2} % |",
            x.period,
            fmt_ns(x.period as f64 * 1e9 / 48000.0),
            fmt_ns(median(&x.bass)),
            fmt_ns(crate::stats::quantile(&x.bass, 0.99)),
            x.bass.len(),
            fmt_ns(median(&x.jack)),
            fmt_ns(crate::stats::quantile(&x.jack, 0.99)),
            x.jack.len(),
            fmt_ratio(median(&x.bass) / median(&x.jack)),
            fmt_ns(median(&x.bass_stamp)),
            x.bassd_cpu * 100.0,
            x.jackd_cpu * 100.0
        );
    }
    let _ = writeln!(
        md,
        "\nThe last columns but two: the reader's time minus the chunk's own timestamp (`mono_ns`, documented as the \
         CLOCK_MONOTONIC of the chunk's first frame). Through the jack plugin bassd flags these timestamps \
         TIME_ESTIMATED; if they marked the first frame this column would be at least one chunk long.\n"
    );
    if e.cpu.is_empty() {
        return;
    }
    let _ = writeln!(md, "## 5. CPU of bassd, and of readers\n");
    let _ = writeln!(
        md,
        "`bassd --acquire sim:silence --rate 48000 --frames N` (the simulated device, paced by absolute-deadline \
         sleeps, no ALSA), two reader processes: one reading every chunk (`Port::wait` for the next frame), one \
         reading 1 s blocks (`Port::wait` for the frame one second ahead). CPU = on-CPU time of all threads \
         (/proc/PID/task/*/schedstat) over {:.0} s, as a share of one core; one repetition. The jack rows of part 4 \
         give bassd's CPU through ALSA.\n",
        e.seconds
    );
    let _ = writeln!(md, "| chunk | chunks/s | bassd | bassd RSS (KiB) | reader, every chunk | reader waiting for 1 s blocks | its sleeps/s (voluntary context switches) |");
    let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|");
    for c in &e.cpu {
        let _ = writeln!(
            md,
            "| {} | {:.0} | {:.2} % | {} | {:.2} % | {:.3} % | {:.0} |",
            c.chunk,
            48000.0 / c.chunk as f64,
            c.bassd * 100.0,
            c.bassd_rss.rss,
            c.reader * 100.0,
            c.waiter * 100.0,
            c.waiter_wakes
        );
    }
    md.push('\n');
}

pub(super) fn memory_section(r: &Results, md: &mut String) {
    let Some(m) = &r.memory else { return };
    let _ = writeln!(md, "## 6. Memory\n");
    let _ = writeln!(
        md,
        "44.1 kHz stereo, 2205-frame chunks. The writer process fills the window, then publishes a chunk every 5 ms for \
         1.5 s; a *tail* reader reads every new chunk, a *full* reader reads the whole window at every chunk; the \
         *original* reader copies the whole port (original design). Resident memory from /proc/PID/status at the end \
         (KiB): RSS (of which shared memory = the port mapping, and anonymous = private). *Baseline* = this benchmark \
         binary before opening any port.\n"
    );
    let _ = writeln!(md, "| window | window bytes | port file | header + chunk tables | allocated (tmpfs) | writer RSS (shm / anon) | tail reader RSS (shm / anon) | full reader RSS (shm / anon) | original reader RSS (shm / anon) | baseline RSS |");
    let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for x in m {
        let f = |s: &crate::procs::Rss| format!("{} ({} / {})", s.rss, s.shmem, s.anon);
        let _ = writeln!(
            md,
            "| {} s | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            x.window_s,
            x.window_bytes,
            x.file_bytes,
            x.overhead_bytes,
            x.allocated_bytes,
            f(&x.writer),
            f(&x.tail_reader),
            f(&x.full_reader),
            f(&x.orig_reader),
            x.baseline.rss
        );
    }
    let _ = writeln!(
        md,
        "\nThe port's shared memory is counted once however many processes map it (RssShmem appears in each mapper's \
         RSS, but it is the same pages; Pss divides it). A bass reader's private memory is its own buffers; an original-design \
         reader holds a private copy of the whole window.\n"
    );
}
