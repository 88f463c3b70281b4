% Edge cases of the MEX gateway, against ports made with its own writer
% commands (no broker): timeouts that are not whole milliseconds, range checks of every numeric
% argument, text where a number goes, and handles across `clear bass_mex` (an unload, as
% `clear functions` / Matlab's `clear mex`). Any failed assertion is an error (exit status 1).
function test_mex_edges()
  w = bass_mex('WriterCreate', 'edges', 'octave-test', 48000, 4, 3, 2);
  h = bass_mex('Open', 'edges');
  bass_mex('Publish', w, int32(1:8));   % frames 1..4
  rt = getenv('BASS_RUNTIME_DIR');

  % --- Wait: any timeout ends when due (before: fractions of a millisecond spun forever).
  for t = [0.1234, 1/3, 0.0005, 0.00001, 0]
    expect_error('bass:timeout', @() bass_mex('Wait', h, 5, t), '');
  end
  assert(bass_mex('Wait', h, 4, 0) == 4);
  assert(bass_mex('Wait', h, 4, Inf) == 4);
  assert(bass_mex('Wait', h, 3, 0.0005) == 4);
  expect_error('bass:badArgument', @() bass_mex('Wait', h, 5, -1), 'timeoutSeconds');
  expect_error('bass:badArgument', @() bass_mex('Wait', h, 5, -Inf), 'timeoutSeconds');
  expect_error('bass:badArgument', @() bass_mex('Wait', h, 5, NaN), 'timeoutSeconds');
  expect_error('bass:badArgument', @() bass_mex('Wait', h, 5, '1'), 'timeoutSeconds');
  % text is not its character code: '5' would be frame 53
  expect_error('bass:badArgument', @() bass_mex('Wait', h, '5', 0), 'frame');
  expect_error('bass:badArgument', @() bass_mex('Wait', h, 2^64, 0), 'frame');
  expect_error('bass:badArgument', @() bass_mex('Wait', h, 1.5, 0), 'frame');

  % --- every numeric argument: finite, integral, within its C type, not text
  bad = {-1, 0.5, NaN, Inf, -Inf, 'a', true, [1 2], 1i, int64(-1)};
  for k = 1:numel(bad)
    expect_error('bass:badArgument', @() bass_mex('GetAudioData', h, bad{k}, 1), 'N');
    expect_error('bass:badArgument', @() bass_mex('GetAudioData', h, 4, bad{k}), 'nfr');
    expect_error('bass:badArgument', @() bass_mex('GetAudioDataMulti', h, bad{k}, 1), 'N');
    expect_error('bass:badArgument', @() bass_mex('Acquire', 'sim:pattern', bad{k}, 480, 100, 2, 'no-such-broker'), 'sampleRate');
    expect_error('bass:badArgument', @() bass_mex('WriterCreate', 'x', 'x', 48000, 4, 3, bad{k}), 'channels');
  end
  expect_error('bass:badArgument', @() bass_mex('GetAudioData', h, 4, 2^64), 'nfr');
  expect_error('bass:badArgument', @() bass_mex('GetAudioData', h, 4, 1, 'yes'), 'noLoss');
  % values too big for uint32 (before: 2^32+1 Hz became 1 Hz, 2^40 channels became stereo)
  expect_error('bass:badArgument', @() bass_mex('Acquire', 'sim:pattern', 2^32 + 1, 480, 100, 2, 'no-such-broker'), 'sampleRate');
  expect_error('bass:badArgument', @() bass_mex('Acquire', 'sim:pattern', 48000, 2^32 + 480, 100, 2, 'no-such-broker'), 'nFramesPerChunk');
  expect_error('bass:badArgument', @() bass_mex('Acquire', 'sim:pattern', 48000, 480, uint64(2)^32, 2, 'no-such-broker'), 'nChunksOnPort');
  expect_error('bass:badArgument', @() bass_mex('Acquire', 'sim:pattern', 48000, 480, 100, 2^40, 'no-such-broker'), 'channels');
  expect_error('bass:badArgument', @() bass_mex('Acquire', 'sim:pattern', 48000, 480, 100, 2, 42), 'broker');
  expect_error('bass:badArgument', @() bass_mex('Acquire', 42, 48000, 480, 100), 'device');
  expect_error('bass:badArgument', @() bass_mex('WriterCreate', 'x', 'x', 2^32 + 48000, 4, 3, 2), 'rate');
  % in range: reaches the broker (none here)
  expect_error('bass:noBroker', @() bass_mex('Acquire', 'sim:pattern', 2^32 - 1, 480, 100, uint8(2), 'no-such-broker'), '');
  [l, r, nfr, n] = bass_mex('GetAudioData', h, uint64(2)^64 - 1, int8(1));
  assert(n == 4 && nfr == 5 && isequal(l, int32([1; 3; 5; 7])));

  % --- handles: unique across unloads; a stale one is refused, never another port's
  expect_error('bass:invalidHandle', @() bass_mex('Info', uint64(16)), '');
  expect_error('bass:invalidHandle', @() bass_mex('Close', w), '');          % a writer is not a port
  h1 = bass_mex('Open', 'edges');
  bass_mex('Close', h1);
  h2 = bass_mex('Open', 'edges');
  assert(h2 ~= h1, 'a handle number was reused within a load');
  expect_error('bass:invalidHandle', @() bass_mex('Close', h1), '');
  bass_mex('Info', h2);                                                       % still open
  clear bass_mex                                                              % unload: closes h, h2, w
  h3 = bass_mex('Open', 'edges');
  assert(h3 ~= h1 && h3 ~= h2 && h3 ~= h, 'a handle number was reused after an unload');
  expect_error('bass:invalidHandle', @() bass_mex('Close', h2), 'earlier load');
  expect_error('bass:invalidHandle', @() bass_mex('Publish', w, int32(1:8)), 'earlier load');
  info = bass_mex('Info', h3);
  assert(strcmp(info.state, 'stopped'), info.state);                          % the unload closed the writer
  bass_mex('Close', h3);

  % --- nothing leaks when the MEX is unloaded with raw handles open
  % (before: 200 cycles left 206 fds and 200 mappings of the port)
  clear bass_mex
  n0 = numel(readdir('/proc/self/fd'));
  for k = 1:200
    hk = bass_mex('Open', 'edges');
    clear bass_mex
  end
  n1 = numel(readdir('/proc/self/fd'));
  maps = numel(strfind(fileread('/proc/self/maps'), rt));
  assert(n1 <= n0 + 2, sprintf('file descriptors grew from %d to %d', n0, n1));
  assert(maps == 0, sprintf('%d mappings of ports left after the unloads', maps));

  % --- a Bass object kept across an unload still reads, and deletes without error
  b = Bass('edges');
  b.PortInfo();
  clear functions
  info = b.PortInfo();                                                        % reopened transparently
  assert(strcmp(info.state, 'stopped'));
  [l, ~, ~, n] = b.getAudioData(4, 1);
  assert(n == 4 && isequal(l, int32([1; 3; 5; 7])));
  clear functions
  lastwarn('');
  clear b
  [msg, ~] = lastwarn();
  assert(isempty(msg), ['delete warned: ' msg]);
  disp('test_mex_edges: all assertions passed');
end

function expect_error(id, fn, text)
  try
    fn();
  catch e
    assert(strcmp(e.identifier, id), sprintf('expected %s, got %s: %s', id, e.identifier, e.message));
    assert(isempty(text) || ~isempty(strfind(e.message, text)), sprintf('message "%s" does not name %s', e.message, text));
    return;
  end
  error('test:fail', 'expected error %s', id);
end
