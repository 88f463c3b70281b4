//! bass-bench: the benchmark harness of bass (`make bench`).
//!
//! Every comparison is measured side by side in one run and printed as a ratio of
//! medians over several repetitions; the results go to docs/performance.md with PNG plots.
//!
//! Usage: `bass-bench [--quick] [--parts 1,2,3,4,5,6,7,8] [--docs DIR]`;
//! `bass-bench child ROLE ARGS...` is this binary's own helper-process mode.
// `unsafe` only in the modules marked below, each block with its SAFETY comment: the bench
// measures the C ABI, raw futexes, the seed's own port and JACK at their edges.
#![deny(unsafe_code)]

mod align;
mod callbacks;
#[allow(unsafe_code)] // kill(2) on bassd
mod e2e;
#[allow(unsafe_code)] // libjack through its C API
mod jack;
mod machine;
mod memory;
#[allow(unsafe_code)] // the seed's original port, in shared memory
mod original;
#[allow(unsafe_code)] // kill(2) on the PipeWire clients
mod pipewire;
mod plot;
#[allow(unsafe_code)] // clock_gettime(CLOCK_PROCESS_CPUTIME_ID)
mod procs;
#[allow(unsafe_code)] // clock_gettime(CLOCK_THREAD_CPUTIME_ID)
mod publish;
#[allow(unsafe_code)] // the C ABI of libbassclient
mod read;
mod report;
#[allow(unsafe_code)] // the seed's shared memory
mod shm;
mod stats;
mod wake;
mod workload;

use std::path::PathBuf;

/// Options of a run.
#[derive(clap::Parser, Debug)]
#[command(name = "bass-bench", about = "The bass benchmark harness (make bench)")]
pub struct Opts {
    /// Fewer repetitions and shorter runs (for development; not for the published numbers)
    #[arg(long)]
    pub quick: bool,
    /// Parts to run, e.g. 1,3
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 2, 3, 4, 5, 6, 7, 8],
          value_parser = clap::value_parser!(u32).range(1..=8))]
    pub parts: Vec<u32>,
    /// Where performance.md and the PNGs go
    #[arg(long, value_name = "DIR", default_value = "docs")]
    pub docs: PathBuf,
}

fn main() {
    // The bench's scratch files, ports and brokers live in /dev/shm as before, also when run
    // as root (whose brokers default to /run/bass): children and bassd inherit this.
    // Set at the very start, before any thread exists.
    if std::env::var_os(bassport::paths::RUNTIME_DIR_ENV).map_or(true, |d| d.is_empty()) {
        std::env::set_var(bassport::paths::RUNTIME_DIR_ENV, bassport::paths::USER_RUNTIME_DIR);
    }
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("child") {
        let role = args.get(1).expect("child ROLE").clone();
        child(&role, &args[2..]);
        return;
    }
    let opts = <Opts as clap::Parser>::parse_from(std::iter::once("bass-bench".to_owned()).chain(args));
    let started = std::time::Instant::now();
    let m = machine::Machine::describe();
    println!("bass-bench on {}", m.one_line());
    let _scratch = procs::Scratch::new();
    let mut results = report::Results { machine: m, quick: opts.quick, ..Default::default() };
    let reps = |full: usize| if opts.quick { 2.min(full) } else { full };
    if opts.parts.contains(&1) {
        println!("part 1: read throughput vs memcpy");
        let runs = read::run(reps(15));
        results.read = runs.chosen_rows().to_vec();
        results.read_paths = Some(runs);
        results.copy_loops = Some(read::copy_loops(reps(7)));
        results.info_cost = Some(read::info_cost(reps(7)));
    }
    if opts.parts.contains(&2) {
        println!("part 2: publish cost vs window size and readers, vs the original design");
        results.publish = Some(publish::run(reps(3), opts.quick));
    }
    if opts.parts.contains(&3) {
        println!("part 3: wake latency vs a raw futex and the 250 ms polling client");
        results.wake = Some(wake::run(reps(3), opts.quick));
    }
    if opts.parts.contains(&4) || opts.parts.contains(&5) {
        println!("parts 4 and 5: end to end through ALSA/jack vs a direct JACK client; bassd CPU");
        results.e2e = Some(e2e::run(opts.quick));
    }
    if opts.parts.contains(&6) {
        println!("part 6: memory");
        results.memory = Some(memory::run());
    }
    if opts.parts.contains(&7) {
        println!("part 7: bass vs PipeWire (Dummy-Driver), 1, 8 and 64 clients, interleaved round by round; callback streams vs JACK process callbacks");
        // Four interleaved rounds in a full run: the delay goals take the median of the per-round
        // ratios, which a disturbance of the shared host in one round does not decide.
        let (rounds, secs) = if opts.quick { (2, 1.5) } else { (4, 5.0) };
        results.pipewire = Some(pipewire::run(rounds, secs, !opts.quick));
    }
    if opts.parts.contains(&8) {
        println!("part 8: several sound cards on one frame index through bassd (sim:field, 2 cores loaded)");
        results.align = Some(align::run(opts.quick));
    }
    results.load_end = machine::loadavg();
    results.elapsed_s = started.elapsed().as_secs_f64();
    report::write(&results, &opts.docs);
    println!("wrote {}/performance.md in {:.0} s", opts.docs.display(), results.elapsed_s);
}

fn child(role: &str, args: &[String]) {
    match role {
        "ring-reader" => publish::child_ring_reader(args),
        "orig-reader" => publish::child_orig_reader(args),
        "futex-pong" => wake::child_futex_pong(args),
        "wake-reader" => wake::child_wake_reader(args),
        "stream-reader" => wake::child_stream_reader(args),
        "poll-reader" => wake::child_poll_reader(args),
        "wake-raw-waiter" => wake::child_raw_waiter(args),
        "futex-waiter" => wake::child_futex_waiter(args),
        "mem-reader" => memory::child_reader(args),
        "cpu-reader" => e2e::child_cpu_reader(args),
        "mem-writer" => memory::child_writer(args),
        "mem-orig-reader" => memory::child_orig_reader(args),
        "pw-cmp-reader" => pipewire::child_reader(args),
        "jack-cb-client" => callbacks::child_jack_client(args),
        "cb-stream" => callbacks::child_stream(args),
        other => panic!("unknown child role {other}"),
    }
}
