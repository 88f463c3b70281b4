#!/usr/bin/env bash
# A 15 s link outage (tests/bridge/outage_long.sh); runs beside the other cases.
OUTAGE=15
source "$(dirname "$0")/../outage_long.sh"
