//! `Port::open(NAME)` and the broker's `open-port`: the path first, the broker only when
//! there is no port file; a memfd port handed over by SCM_RIGHTS is taken (sealed); an older
//! broker, a file broker, a reply with several descriptors or no broker at all leave the
//! path's `NotFound`, and no stray descriptor stays open. The "brokers" here are real
//! SEQPACKET sockets in this process answering with hand-written replies.
//!
//! One test in its own process: it sets `BASS_RUNTIME_DIR`.

use std::io::IoSlice;
use std::mem::MaybeUninit;
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bassport::control::{self, PortFd, Reply};
use bassport::{Error, Geometry, Port, PortParams, Writer};
use rustix::net::{
    AddressFamily, SendAncillaryBuffer, SendAncillaryMessage, SendFlags, SocketFlags, SocketType,
};

/// What the fake broker answers to the one request it reads.
#[allow(clippy::large_enum_variant)] // a handful of values per test
enum Answer {
    /// A raw datagram (e.g. an older broker's error).
    Raw(Vec<u8>),
    /// A reply with these descriptors attached.
    WithFds(Reply, Vec<OwnedFd>),
}

fn listen(path: &Path) -> OwnedFd {
    let fd = rustix::net::socket_with(
        AddressFamily::UNIX,
        SocketType::SEQPACKET,
        SocketFlags::CLOEXEC | SocketFlags::NONBLOCK,
        None,
    )
    .unwrap();
    rustix::net::bind(&fd, &rustix::net::SocketAddrUnix::new(path).unwrap()).unwrap();
    rustix::net::listen(&fd, 4).unwrap();
    fd
}

/// Serves one connection on `listener` (bounded: gives up after 10 s); returns how many
/// connections it accepted.
fn serve_once(listener: OwnedFd, answer: Answer) -> JoinHandle<usize> {
    std::thread::spawn(move || {
        let end = Instant::now() + Duration::from_secs(10);
        let conn = loop {
            match rustix::net::accept_with(&listener, SocketFlags::CLOEXEC) {
                Ok(c) => break c,
                Err(_) if Instant::now() < end => std::thread::sleep(Duration::from_millis(2)),
                Err(_) => return 0,
            }
        };
        control::socket::set_timeouts(conn.as_fd(), Some(Duration::from_secs(10)), None).unwrap();
        let _request = control::recv_datagram(conn.as_fd()).unwrap();
        match answer {
            Answer::Raw(bytes) => control::send_datagram(conn.as_fd(), &bytes).unwrap(),
            Answer::WithFds(reply, fds) => send_with_fds(conn.as_fd(), &reply, &fds),
        }
        1
    })
}

fn send_with_fds(c: BorrowedFd<'_>, r: &Reply, fds: &[OwnedFd]) {
    let bytes = control::wire::encode_reply(r);
    let borrowed: Vec<BorrowedFd<'_>> = fds.iter().map(|f| f.as_fd()).collect();
    let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(4))];
    let mut cmsg = SendAncillaryBuffer::new(&mut space);
    assert!(cmsg.push(SendAncillaryMessage::ScmRights(&borrowed)));
    rustix::net::sendmsg(c, &[IoSlice::new(&bytes)], &mut cmsg, SendFlags::NOSIGNAL).unwrap();
}

fn open_fds() -> usize {
    std::fs::read_dir("/proc/self/fd").unwrap().count()
}

fn memfd_port(name: &str) -> Writer {
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 64, chunks_on_port: 4 };
    let params = PortParams { geometry, device: "fallback".into(), group: None };
    Writer::prepare_memfd(name, &params, Some(6)).unwrap().commit().unwrap()
}

fn socket(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("bass-{name}.sock"))
}

#[test]
fn open_by_name_takes_the_broker_s_memfd_only_when_there_is_no_file_and_falls_back_otherwise() {
    let dir = std::env::temp_dir().join(format!("bass-open-fallback-{}", std::process::id()));
    // A leftover of an earlier run with this pid, if any.
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::env::set_var(bassport::paths::RUNTIME_DIR_ENV, &dir);
    let fds_before = open_fds();

    // No broker, no file.
    assert!(matches!(Port::open("none"), Err(Error::NotFound { .. })));

    // A broker handing over a memfd port: taken, sealed, its epoch continued (6 + 1).
    let w = memfd_port("mem");
    assert!(!w.path().exists(), "no file for a memfd port");
    let t = serve_once(
        listen(&socket(&dir, "mem")),
        Answer::WithFds(
            Reply::PortFd(PortFd { epoch: 7, size: w.layout().total_size }),
            vec![w.reader_fd().unwrap().unwrap()],
        ),
    );
    let p = Port::open("mem").expect("the memfd port through the broker");
    assert!(p.size_sealed());
    assert_eq!(p.epoch(), 7);
    assert_eq!(t.join().unwrap(), 1);
    drop(p);

    // An older broker (does not know open-port): the path's NotFound.
    let old = br#"{"version":"bass-control/2","reply":"error","kind":"protocol","message":"unknown variant `open-port`"}"#;
    let t = serve_once(listen(&socket(&dir, "old")), Answer::Raw(old.to_vec()));
    assert!(matches!(Port::open("old"), Err(Error::NotFound { .. })));
    assert_eq!(t.join().unwrap(), 1, "the older broker was asked");

    // A reply with two descriptors: refused, both closed, the path decides.
    let two = vec![w.reader_fd().unwrap().unwrap(), w.reader_fd().unwrap().unwrap()];
    let reply = Reply::PortFd(PortFd { epoch: 7, size: w.layout().total_size });
    let t = serve_once(listen(&socket(&dir, "two")), Answer::WithFds(reply, two));
    assert!(matches!(Port::open("two"), Err(Error::NotFound { .. })));
    assert_eq!(t.join().unwrap(), 1);

    // A port file at the name: opened by path, the broker is not even asked.
    let file_port = Writer::create("file", &file_port_params()).unwrap();
    let listener = listen(&socket(&dir, "file"));
    let p = Port::open("file").expect("the port file");
    assert!(!p.size_sealed(), "a port file is never treated as sealed");
    assert!(
        rustix::net::accept(&listener).is_err(),
        "nobody connected to the broker of a port that has a file"
    );
    drop((p, file_port, listener, w));

    let fds_after = open_fds();
    assert_eq!(fds_after, fds_before, "no descriptor left open by the hand-overs");
    std::fs::remove_dir_all(&dir).unwrap();
}

fn file_port_params() -> PortParams {
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 64, chunks_on_port: 4 };
    PortParams { geometry, device: "fallback-file".into(), group: None }
}
