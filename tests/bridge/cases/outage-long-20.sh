#!/usr/bin/env bash
# A 20 s link outage (tests/bridge/outage_long.sh); runs beside the other cases.
OUTAGE=20
source "$(dirname "$0")/../outage_long.sh"
