#!/usr/bin/env bash
# make bench does not run it (the network bench runs --insecure); run it by hand: scripts/bench-signatures.sh
# serve CPU with and without signatures, 64-frame chunks at 48 kHz (750 chunks/s), loopback.
set -u
B=target/release; D=$(mktemp -d); export BASS_RUNTIME_DIR=$D
$B/bass-bridge credentials $D/r.cred --user robot 2>/dev/null; $B/bass-bridge credentials $D/w.cred --user ws1 --trust $D/r.pub 2>/dev/null; $B/bass-bridge credentials $D/r.cred --trust $D/w.pub 2>/dev/null
$B/bassd --name src --rt-priority 0 --acquire sim:pattern --rate 48000 --frames 64 --chunks 200 --channels 2 >$D/bassd.log 2>&1 & BD=$!
sleep 1
cpu() { awk '{print $14+$15}' /proc/$1/stat; }
for round in 1 2; do
for mode in plain signed; do
  a=(); m=(); if [[ $mode == signed ]]; then a=(--credentials $D/r.cred); m=(--credentials $D/w.cred); fi
  $B/bass-bridge serve --name src --listen "tcp/[::1]:7480" --no-scouting "${a[@]}" >$D/s.log 2>&1 & S=$!
  $B/bass-bridge mirror --source src --name rep --connect "tcp/[::1]:7480" --no-scouting --listen "tcp/[::1]:0" "${m[@]}" --status-file $D/st.json >$D/m.log 2>&1 & M=$!
  sleep 3; s0=$(cpu $S); m0=$(cpu $M); sleep 10; s1=$(cpu $S); m1=$(cpu $M); sleep 1.2
  tail -2 $D/m.log | grep -i error; echo "$mode round $round: serve $(( (s1-s0) ))% mirror $(( (m1-m0) ))% (ticks/10s = % of a core); chunks $(python3 -c "import json;d=json.load(open('$D/st.json'));print(d['chunks_written'], d.get('forged_messages'))")"
  kill $S $M; wait $S $M 2>/dev/null
done; done
kill $BD; rm -rf $D
