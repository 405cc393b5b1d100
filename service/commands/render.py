"""``asrmap render``: the picture of a saved map document."""

from __future__ import annotations

import json
from pathlib import Path

from service.argtypes import distinct_files, output_file

NAME = "render"
HELP = "draw a saved map (asrmap/map/1 JSON) as SVG: topological map beside the global metric map"
EXAMPLE = "asrmap render map.json --svg map.svg"


def add_arguments(p) -> None:
    p.add_argument(
        "map", help="map document written by `asrmap replay --json` or fetched from asrmap/<robot>/map"
    )
    p.add_argument("--svg", metavar="OUT", type=output_file, required=True, help="SVG file to write")


def run(args) -> int:
    from mapper.document import from_document
    from service.render import write_svg

    distinct_files({"MAP": args.map}, {"--svg": args.svg})
    try:
        doc = json.loads(Path(args.map).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{args.map} is not JSON ({e}); expected an asrmap/map/1 document") from e
    except RecursionError as e:
        raise ValueError(f"{args.map}: arrays or objects nested too deeply; expected an asrmap/map/1 "
                         "document") from e
    md = from_document(doc)  # refuses anything that is not an asrmap/map/1 document, naming the field
    write_svg(args.svg, doc, title=f"asrmap map {Path(args.map).name}")
    print(f"wrote {args.svg}: {len(md.asrs)} ASRs, {sum(1 for c in md.cycles if c.accepted)} cycles")
    return 0
