% Conformance driver in GNU Octave (or Matlab): replays vectors.txt through the MEX gateway
% bass_mex (writer and reader C ABI) and writes the file back with the `read` results
% observed. Usage: octave --no-gui -q --eval "driver_octave('vectors.txt', 'out.txt')"
% with bass_mex and this file on the path, BASS_RUNTIME_DIR set.
function driver_octave(vectors, out_path)
  in = fopen(vectors, 'r');
  out = fopen(out_path, 'w');
  name = sprintf('conf-oct-%d', getpid());
  w = [];
  h = [];
  while true
    line = fgetl(in);
    if ~ischar(line)
      break;
    end
    tok = strsplit(strtrim(line), ' ');
    if isempty(tok{1})
      continue;
    end
    switch tok{1}
      case 'case'
        g = str2double(tok(3:6));
        w = bass_mex('WriterCreate', name, 'conformance', g(2), g(3), g(4), g(1));
        h = bass_mex('Open', name);
        fprintf(out, 'case %s %d %d %d %d\n', tok{2}, g);
      case 'publish'
        s = int32(str2double(tok(2:end)));
        bass_mex('Publish', w, s);
        fprintf(out, 'publish%s\n', sprintf(' %d', s));
      case 'read'
        N = parse_u64(tok{2});
        nfr = parse_u64(tok{3});
        [l, r, nfr2, n, loss] = bass_mex('GetAudioData', h, N, nfr);
        inter = [l.'; r.'];
        samples = '';
        if n > 0
          samples = sprintf(' %d', inter(:));  % (sprintf of an empty array would print ' ')
        end
        fprintf(out, 'read %s %s %d %s %d%s\n', u64_str(N), u64_str(nfr), n, u64_str(nfr2), loss, samples);
      case 'readm'
        N = parse_u64(tok{2});
        nfr = parse_u64(tok{3});
        [x, nfr2, n, loss] = bass_mex('GetAudioDataMulti', h, N, nfr);
        samples = '';
        if n > 0
          xt = x.';                            % channels x n: column-major order interleaves
          samples = sprintf(' %d', xt(:));
        end
        fprintf(out, 'readm %s %s %d %s %d%s\n', u64_str(N), u64_str(nfr), n, u64_str(nfr2), loss, samples);
      case 'end'
        bass_mex('Close', h);
        bass_mex('WriterClose', w);
        fprintf(out, 'end\n');
      otherwise
        fprintf(out, '%s\n', strjoin(tok, ' '));
    end
  end
  fclose(in);
  fclose(out);
end

% Exact decimal string -> uint64 (str2double alone rounds above 2^53).
function v = parse_u64(s)
  if numel(s) <= 15
    v = uint64(str2double(s));
  else
    v = uint64(str2double(s(1:end - 9))) * uint64(1e9) + uint64(str2double(s(end - 8:end)));
  end
end

% Exact uint64 -> decimal string (sprintf('%d') goes through double).
function s = u64_str(v)
  v = uint64(v);
  if v == 0
    s = '0';
    return;
  end
  s = '';
  while v > 0
    d = mod(v, uint64(10));            % exact; idivide() goes through double
    s = [char('0' + double(d)) s];
    v = (v - d) / uint64(10);          % an exact multiple of 10: exact
  end
end
