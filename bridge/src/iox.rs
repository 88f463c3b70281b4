//! iceoryx2 export (cargo feature `iceoryx2`, `serve --iceoryx2`): every chunk `serve` reads is
//! also offered on the publish-subscribe service `bass/<broker>/chunks` for iceoryx2-native
//! subscribers on the same machine. Payload: the chunk's samples as a `[i32]` slice,
//! frame-interleaved; user header: [`ChunkHeader`] (type name `BassChunkHeader`), the wire
//! header's fields. The port stays the primary interface: this is an export, it carries no
//! window, and a subscriber that falls behind loses samples by iceoryx2's own rules.
//!
//! iceoryx2's own signal handling is disabled: `serve` handles SIGTERM/SIGINT and drops the
//! publisher, the service and the node in order, which removes their shared memory.

use anyhow::{anyhow, Result};
use iceoryx2::prelude::*;

use crate::wire;

/// The user header of every sample. Mirrored in Python by `tests/bridge/iox_subscriber.py`.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, ZeroCopySend)]
#[type_name("BassChunkHeader")]
pub struct ChunkHeader {
    /// Sending `serve` instance.
    pub instance: u64,
    /// Source acquisition epoch.
    pub epoch: u64,
    /// Chunk sequence number.
    pub sequence: u64,
    /// First frame index.
    pub first_frame: u64,
    /// Source CLOCK_MONOTONIC of the first frame.
    pub mono_ns: u64,
    /// Source CLOCK_REALTIME of the first frame.
    pub realtime_ns: u64,
    /// CLOCK_MONOTONIC when offered.
    pub send_mono_ns: u64,
    /// Frames serve could not send on the network so far.
    pub source_lost: u64,
    /// Header version: 2 since the flags are the wire format 2's (the port's chunk flags,
    /// SOURCE_LOSS 16); 1 had the wire format 1's numbering.
    pub version: u32,
    /// [`wire::flags`].
    pub flags: u32,
    /// Frames in the chunk.
    pub frames: u32,
    /// Channels.
    pub channels: u32,
    /// Hz.
    pub sample_rate: u32,
    /// Source nChunksOnPort.
    pub chunks_on_port: u32,
    /// Bound (ns) of `mono_ns` (and `realtime_ns`): the first frame's true capture time lies
    /// within `± bound_ns`; `u64::MAX` if none is known (version 3).
    pub bound_ns: u64,
    /// Bit c: channel c's frames are zero-filled, lost by the device feeding it (version 3).
    pub missing_channels: u64,
    /// Bit c: channel c is not yet aligned within its bound (version 3).
    pub unaligned_channels: u64,
}

const _: () = assert!(core::mem::size_of::<ChunkHeader>() == 112);

/// [`ChunkHeader::version`]: 3 since the header carries the bound and the channel masks
/// (112 bytes; a subscriber built for the 88-byte header of version 2 is refused by iceoryx2
/// when it opens the service, the header's size having changed).
pub const VERSION: u32 = 3;

/// The iceoryx2 node, service and publisher (dropped in reverse order of creation).
pub struct Exporter {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, [i32], ChunkHeader>,
    _service:
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [i32], ChunkHeader>,
    _node: Node<ipc::Service>,
    failures: u64,
}

impl Exporter {
    /// Creates (or opens) `bass/<broker>/chunks`.
    pub fn new(broker: &str) -> Result<Exporter> {
        let node = NodeBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| anyhow!("iceoryx2 node: {e:?}"))?;
        let name = format!("bass/{broker}/chunks");
        let service = node
            .service_builder(
                &name.as_str().try_into().map_err(|e| anyhow!("iceoryx2 service name {name}: {e:?}"))?,
            )
            .publish_subscribe::<[i32]>()
            .user_header::<ChunkHeader>()
            .open_or_create()
            .map_err(|e| anyhow!("iceoryx2 service {name}: {e:?}"))?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(4096)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|e| anyhow!("iceoryx2 publisher: {e:?}"))?;
        tracing::info!(service = %name, "iceoryx2 export");
        Ok(Exporter { publisher, _service: service, _node: node, failures: 0 })
    }

    /// Offers one chunk (interleaved samples; zeros for a GAP chunk). Never blocks.
    pub fn publish(&mut self, h: &wire::Header, samples: &[i32]) {
        let r = (|| -> Result<()> {
            let mut s =
                self.publisher.loan_slice_uninit(samples.len()).map_err(|e| anyhow!("loan: {e:?}"))?;
            *s.user_header_mut() = ChunkHeader {
                instance: h.instance,
                epoch: h.epoch,
                sequence: h.sequence,
                first_frame: h.first_frame,
                mono_ns: h.mono_ns,
                realtime_ns: h.realtime_ns,
                send_mono_ns: h.send_mono_ns,
                source_lost: h.source_lost,
                version: VERSION,
                flags: h.flags,
                frames: h.frames,
                channels: u32::from(h.channels),
                sample_rate: h.sample_rate,
                chunks_on_port: h.chunks_on_port,
                bound_ns: h.bound_ns,
                missing_channels: h.missing_channels,
                unaligned_channels: h.unaligned_channels,
            };
            let s = s.write_from_slice(samples);
            s.send().map_err(|e| anyhow!("send: {e:?}"))?;
            Ok(())
        })();
        if let Err(e) = r {
            self.failures += 1;
            if self.failures.is_power_of_two() {
                tracing::warn!(failures = self.failures, "iceoryx2 export: {e:#}");
            }
        }
    }
}
