% Unit tests of the MEX gateway against ports made with its own writer commands (no broker).
% Run: octave --no-gui -q --eval "test_mex" with bass_mex on the path, BASS_RUNTIME_DIR set.
% Any failed assertion is an error: Octave exits with status 1.
function test_mex()
  pat = @(f, c) int32(bitor(bitshift(bitand(uint64(f), uint64(67108863)), 6), uint64(c)));  % f < 2^25 here

  w = bass_mex('WriterCreate', 'mex', 'octave-test', 48000, 4, 3, 2);
  h = bass_mex('Open', 'mex');
  % a new writer's port is 'starting' until its first chunk (format 2.1; was shown as 'unknown')
  info = bass_mex('Info', h);
  assert(strcmp(info.state, 'starting') && info.nFramesOnPort == 12 && info.lastFrameIndex == 0);
  % WriterCreate takes rate, nfpc, ncop, channels (Acquire's order)
  assert(info.sampleRate == 48000 && info.nFramesPerChunk == 4 && info.nChunksOnPort == 3 && info.channels == 2);
  assert(isa(info.lastFrameIndex, 'uint64'));

  % frame 0 is the zero frame; nfr in the future gives n = 0
  [l, r, nfr, n, loss] = bass_mex('GetAudioData', h, 5, 0);
  assert(n == 1 && nfr == 1 && loss == 0 && l == 0 && r == 0);
  [l, r, nfr, n] = bass_mex('GetAudioData', h, 5, 1);
  assert(n == 0 && nfr == 1 && isempty(l) && isempty(r));

  % publish frames 1..20 of the pattern (5 chunks of 4 frames): the window holds 9..20
  for k = 0:4
    f = (4 * k + 1):(4 * k + 4);
    chunk = [pat(f, 0); pat(f, 1)];
    lfi = bass_mex('Publish', w, chunk(:).');
  end
  assert(lfi == 20);

  [l, r, nfr, n, loss] = bass_mex('GetAudioData', h, 3, uint64(12));
  assert(isa(l, 'int32') && isa(r, 'int32') && iscolumn(l) && isa(nfr, 'uint64'));
  assert(n == 3 && nfr == 15 && loss == 0);
  assert(isequal(l, pat(12:14, 0).') && isequal(r, pat(12:14, 1).'));

  % a loss moves nfr to the oldest frame and counts the frames that left
  [l, ~, nfr, n, loss] = bass_mex('GetAudioData', h, 100, 2);
  assert(n == 12 && loss == 7 && nfr == 21 && isequal(l, pat(9:20, 0).'));

  % ... or raises bass:lost when asked to
  try
    bass_mex('GetAudioData', h, 4, 2, true);
    error('test:fail', 'no error');
  catch e
    assert(strcmp(e.identifier, 'bass:lost'), e.identifier);
  end

  % Wait: returns the last frame index; times out with bass:timeout
  assert(bass_mex('Wait', h, 20, 1) == 20);
  try
    bass_mex('Wait', h, 21, 0.15);
    error('test:fail', 'no error');
  catch e
    assert(strcmp(e.identifier, 'bass:timeout'), e.identifier);
  end

  % the writer closes: a waiting reader gets bass:stopped
  bass_mex('WriterClose', w);
  try
    bass_mex('Wait', h, 21, 5);
    error('test:fail', 'no error');
  catch e
    assert(strcmp(e.identifier, 'bass:stopped'), e.identifier);
  end

  bass_mex('Close', h);
  expect_error('bass:invalidHandle', @() bass_mex('Close', h));
  expect_error('bass:noPort', @() bass_mex('Open', 'no-such-port'));
  expect_error('bass:noBroker', @() bass_mex('Status', 'no-such-broker'));
  expect_error('bass:usage', @() bass_mex('NoSuchCommand'));
  expect_error('bass:badArgument', @() bass_mex('GetAudioData', uint64(1), -1, 0));
  disp('test_mex: all assertions passed');
end
