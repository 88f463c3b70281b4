"""The literal model of the BASS port and of the formal getAudioData, written from the seed
(shared/seeds/bass-basc-documentation.rst), not from libbassclient.

The port is what the seed describes: two arrays (left, right) of nFOP = nFPC * nCOP
samples, filled with zeros at the start of the acquisition, shifted by one chunk every
time a chunk arrives (the oldest chunk drops out at index 0, the new one is appended at
the end), and a lastFrameIndex incremented by nFPC per chunk. getAudioData is the seed's
pseudo-code, line for line, with unbounded Python integers.
"""


class SeedPort:
    """The `Audio` port of BASS as shifting arrays: `left` and `right` (the seed's two), or
    one array per channel for ports of other widths (`channel[c]`; left/right are channel[0]
    and channel[1])."""

    def __init__(self, sample_rate, n_frames_per_chunk, n_chunks_on_port, channels=2):
        self.sampleRate = sample_rate
        self.nFramesPerChunk = n_frames_per_chunk
        self.nChunksOnPort = n_chunks_on_port
        nfop = n_frames_per_chunk * n_chunks_on_port
        self.channel = [[0] * nfop for _ in range(channels)]
        self.lastFrameIndex = 0

    @property
    def left(self):
        return self.channel[0]

    @property
    def right(self):
        return self.channel[1]

    def add_chunk(self, *chunks):
        """A new chunk arrives (one list per channel): shift the arrays, deleting the oldest chunk."""
        nfpc = self.nFramesPerChunk
        assert len(chunks) == len(self.channel) and all(len(c) == nfpc for c in chunks)
        self.channel = [array[nfpc:] + list(chunk) for array, chunk in zip(self.channel, chunks)]
        self.lastFrameIndex += nfpc


def get_audio_data(N, Audio, nfr):
    """The seed's formal getAudioData. Returns (l, r, n, nfr, loss)."""
    nFOP = Audio.nFramesPerChunk * Audio.nChunksOnPort
    lfi = Audio.lastFrameIndex
    ofi = max(0, lfi - nFOP + 1)  # if the acquisition just started, ofi equals 0
    # Detect a data loss
    loss = 0
    if nfr < ofi:
        loss = ofi - nfr
        nfr = ofi
    # Compute the starting position in the left and right input arrays
    pos = nFOP - (lfi - nfr + 1)
    # Fill the output arrays l and r
    l, r = [], []
    n = 0
    while n < N and pos < nFOP:
        l.append(Audio.left[pos])
        r.append(Audio.right[pos])
        n = n + 1
        pos = pos + 1
        nfr = nfr + 1
    return l, r, n, nfr, loss


def get_audio_data_multi(N, Audio, nfr):
    """getAudioData over every channel of the port: the same algorithm, one output per array.
    Returns (channels[c][n], n, nfr, loss)."""
    nFOP = Audio.nFramesPerChunk * Audio.nChunksOnPort
    lfi = Audio.lastFrameIndex
    ofi = max(0, lfi - nFOP + 1)
    loss = 0
    if nfr < ofi:
        loss = ofi - nfr
        nfr = ofi
    pos = nFOP - (lfi - nfr + 1)
    out = [[] for _ in Audio.channel]
    n = 0
    while n < N and pos < nFOP:
        for c, array in enumerate(Audio.channel):
            out[c].append(array[pos])
        n = n + 1
        pos = pos + 1
        nfr = nfr + 1
    return out, n, nfr, loss
