"""Build ``dune-traffic-excerpt.jsonl.gz`` (the recorded DUNE peer the CI tests use) from the
full capture ``/work/shared/data/dune-traffic/dune-traffic.jsonl.gz`` (6.1 MB, not in the
repository; its README describes the recording).

Kept, in the capture's order and format: every datagram we sent, every Announce, every
datagram of a type the deploy decodes (``mpcasv.io.link.USED``, one definition: since session
48 PlanControlState, SetServoPosition and UsblFixExtended too), every relay (our echoes,
messages not addressed to us or to broadcast), and one in ``SUBSAMPLE`` of the rest (DUNE's
bus traffic, which the deploy only counts). Deterministic.

    python tests/data/make_dune_traffic_excerpt.py [FULL_CAPTURE]
"""

import gzip
import json
import struct
import sys
from pathlib import Path

from mpcasv.io.link import USED

SUBSAMPLE = 50
US = 0x4001


def main(src: str = "/work/shared/data/dune-traffic/dune-traffic.jsonl.gz") -> None:
    out = Path(__file__).with_name("dune-traffic-excerpt.jsonl.gz")
    kept = total = other = 0
    with gzip.open(src, "rt") as fin, gzip.open(out, "wt", compresslevel=9) as fout:
        for line in fin:
            total += 1
            d = json.loads(line)
            _, mgid, _, _, src_id, _, dst, _ = struct.unpack_from("<HHHdHBHB",
                                                                  bytes.fromhex(d["hex"][:40]))
            keep = d.get("sent") or mgid in USED or src_id == US or dst not in (US, 0xFFFF)
            if not keep:
                other += 1
                keep = other % SUBSAMPLE == 1
            if keep:
                fout.write(line)
                kept += 1
    print(f"{out}: {kept} of {total} datagrams")


if __name__ == "__main__":
    main(*sys.argv[1:])
