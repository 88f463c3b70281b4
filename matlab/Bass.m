% Bass: a bass broker and its port, in the vocabulary of the BASS documentation.
%
%   bass = Bass();                              % broker "default" (Bass('name') for another)
%   bass.ListDevices()                          % prints name and description of each device
%   bass.Acquire('sim:pattern', 44100, 2205, 20)   % or bass.Acquire('-a', 'hw:1,0', 44100, 2205, 20)
%   bass.GetBlocks(1, 88200, 0);                % the BASC client: prints the seed's lines
%   [l, r, nfr, n, loss] = bass.getAudioData(12000, nfr)   % the formal getAudioData
%   lfi = bass.Wait(frame, timeoutSeconds)      % blocks until frame is published (Ctrl-C safe)
%   c = bass.ChunkInfo(frame)                   % the chunk holding frame: timestamps, c.gap, c.late, ...
%   s = bass.Status()
%   d = bass.Devices()                          % per device (several cards): ratio, lock, losses
%   bass.Stop()
%
% Samples are int32 columns; frame indices (nfr, lastFrameIndex) are uint64 and frames are
% numbered from 1 (frame 0 is the zero frame before the acquisition). Errors have the
% identifiers of bass_mex (bass:noPort, bass:noBroker, bass:timeout, bass:lost, ...).
classdef Bass < handle
  properties (SetAccess = private)
    broker = 'default';   % broker (and port) name
  end
  properties (Hidden)
    % Port handle from bass_mex('Open'), opened on first use. Hidden rather than private:
    % an object kept across `clear functions` (whose class Octave reloads) may no longer
    % touch private members, not even from delete.
    h = [];
  end

  methods
    function obj = Bass(broker)
      if nargin > 0
        obj.broker = broker;
      end
    end

    function delete(obj)
      % Closes the port. Calls no private method: an object kept across `clear functions`
      % is deleted after its class was reloaded, when Octave refuses private method calls
      % ("closePort has private access"). A handle from before the reload is refused by
      % bass_mex (bass:invalidHandle; the unload already closed its port): ignored here.
      if ~isempty(obj.h)
        try
          bass_mex('Close', obj.h);
        catch
        end
      end
    end

    function epoch = Acquire(obj, varargin)
      % Acquire(device = 'hw:1,0', sampleRate = 44100, nFramesPerChunk = 2205, nChunksOnPort = 20,
      % channels = 2) starts (or restarts) the acquisition. `device` may be a cell array of
      % devices, the master first (docs/multi-device.md), and `channels` then one count for every
      % device or a vector of one count per device. A leading '-a' (genomix's asynchronous flag)
      % is accepted and ignored: the broker always acquires in the background.
      if ~isempty(varargin) && ischar(varargin{1}) && strcmp(varargin{1}, '-a')
        varargin(1) = [];
      end
      if numel(varargin) > 5
        error('bass:badArgument', 'Acquire takes at most 5 arguments (device, rate, nFPC, nCOP, channels), not %d', numel(varargin));
      end
      defaults = {'hw:1,0', 44100, 2205, 20, 2};
      defaults(1:numel(varargin)) = varargin;
      epoch = bass_mex('Acquire', defaults{:}, obj.broker);
      obj.closePort();   % the new acquisition has a new port
    end

    function Stop(obj)
      bass_mex('Stop', obj.broker);
    end

    function devices = ListDevices(obj)
      % Prints the devices (name, description); returns them as an n x 2 cell if asked.
      if nargout > 0
        devices = bass_mex('ListDevices', obj.broker);
      else
        bass_mex('ListDevices', obj.broker);
      end
    end

    function s = Status(obj)
      s = bass_mex('Status', obj.broker);
    end

    function d = Devices(obj)
      % The acquisition's devices, master first: a cell array of structs (name, role,
      % firstChannel, channels, state, ratioPpm, errorEstimate, locks, xruns, unplugs,
      % missingFrames, unalignedFrames; docs/multi-device.md), as Status().devices.
      s = bass_mex('Status', obj.broker);
      d = s.devices;
    end

    function info = PortInfo(obj)
      % A snapshot of the port: every field of bass_port_info (geometry, lastFrameIndex,
      % state, xruns, gapFrames, lostUpstreamFrames, startedMonoNs, heartbeatMonoNs, ...).
      info = obj.call('Info');
    end

    function c = ChunkInfo(obj, frame)
      % The chunk holding frame: firstFrame, frames, monoNs, realtimeNs, flags and one
      % logical per flag (gap: zero-filled frames the device or the network did not deliver;
      % discontinuity; timeEstimated; late: delivered in a catch-up burst). bass:lost if the
      % frame left the window, bass:notYet if it is not published yet.
      c = obj.call('ChunkInfo', frame);
    end

    function [l, r, nfr, n, loss] = getAudioData(obj, N, nfr)
      % The formal getAudioData: up to N frames from nfr; never blocks. A port replaced by a
      % new acquisition (the broker restarted: bass:restarted) or whose broker died
      % (bass:writerGone) is an error, not n = 0 forever; the next call opens the new port.
      [l, r, nfr, n, loss] = obj.call('GetAudioData', N, nfr);
    end

    function lfi = Wait(obj, frame, timeout)
      % Blocks until frame is published (timeout in seconds, default Inf); returns the last
      % frame index. Ctrl-C returns to the prompt (error bass:interrupted). bass:restarted
      % and bass:writerGone as for getAudioData.
      if nargin < 3
        timeout = Inf;
      end
      lfi = obj.call('Wait', frame, timeout);
    end

    function block = GetBlocks(obj, nBlocks, nFramesPerBlock, startOffs, period)
      % GetBlocks(nBlocks = 1, nFramesPerBlock = 12000, startOffs = -12000, period = 0.25):
      % the BASC service. Calls getAudioData once per period, to request a new block or
      % complete the current one, printing the seed's lines. nBlocks = 0 runs until Ctrl-C.
      % startOffs counts from the next frame to be published (0: fresh frames only, -N: the
      % last N frames on the port). block = GetBlocks(...) returns the last complete block as
      % [left right]; called without an output (the seed's `bass.GetBlocks(1, 88200, 0)`) it
      % returns nothing, so that no semicolon is needed to keep the block off the screen.
      if nargin < 2, nBlocks = 1; end
      if nargin < 3, nFramesPerBlock = 12000; end
      if nargin < 4, startOffs = -12000; end
      if nargin < 5, period = 0.25; end
      info = obj.PortInfo();
      if strcmp(info.state, 'capturing')
        % Start the period clock half a chunk after a publish (see examples-c/basc.c).
        obj.Wait(info.lastFrameIndex + 1, 10);
        pause(info.nFramesPerChunk / info.sampleRate / 2);
        info = obj.PortInfo();
      end
      nfr = uint64(max(0, double(info.lastFrameIndex) + 1 + startOffs));
      last = zeros(0, 2, 'int32');
      L = zeros(nFramesPerBlock, 1, 'int32');
      R = L;
      got = 0;
      blocks = 0;
      t0 = tic;
      k = 0;
      while nBlocks == 0 || blocks < nBlocks
        k = k + 1;
        pause(max(0, k * period - toc(t0)));
        requested = nFramesPerBlock - got;
        [l, r, nfr, n, loss] = obj.getAudioData(requested, nfr);
        fprintf('Requested %6d frames, got %6d.\n', requested, n);
        if loss > 0
          fprintf('!!Lost %d frames!!\n', loss);
        end
        L(got + 1:got + n) = l;
        R(got + 1:got + n) = r;
        got = got + n;
        if got == nFramesPerBlock
          fprintf('A new block is ready to be processed.\n');
          last = [L R];
          blocks = blocks + 1;
          got = 0;
        end
      end
      if nargout > 0
        block = last;
      end
    end
  end

  methods (Hidden)
    % Helpers, hidden rather than private: an object kept across `clear functions` may call
    % only public methods (Octave re-checks access against the reloaded class).
    function h = port(obj)
      if isempty(obj.h)
        obj.h = bass_mex('Open', obj.broker);
      end
      h = obj.h;
    end

    function varargout = call(obj, cmd, varargin)
      % bass_mex(cmd, port, ...). A handle from an earlier load of bass_mex (`clear
      % functions`; its port was closed by the unload) is replaced by a new one, once. On
      % bass:restarted or bass:writerGone the port is closed before the error is rethrown,
      % so that the next call opens the broker's current port.
      for attempt = 1:2
        try
          [varargout{1:max(1, nargout)}] = bass_mex(cmd, obj.port(), varargin{:});
          return;
        catch e
          if strcmp(e.identifier, 'bass:invalidHandle') && attempt == 1
            obj.h = [];
            continue;
          end
          if any(strcmp(e.identifier, {'bass:restarted', 'bass:writerGone'}))
            obj.closePort();
          end
          rethrow(e);
        end
      end
    end

    function closePort(obj)
      if ~isempty(obj.h)
        try
          bass_mex('Close', obj.h);
        catch
        end
        obj.h = [];
      end
    end
  end
end
