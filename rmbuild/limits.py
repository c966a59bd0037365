"""What rmbuild refuses to read, in one place: each limit bounds the memory or the time that one input can
cost, far above what real data needs (docs/reliability.md lists them for users).

An input beyond a limit is an :class:`rmbuild.errors.InputError` (exit 2) that names the file, the line or
row where one applies, and the limit. The limits are checked where the values enter (readers, ingest's
shared checks, the floor plan's parser), before anything of their size is allocated.
"""

from __future__ import annotations

#: m; |x| and |y| of any position (poses, fixes, anchors, floor plan vertices in local metres): 100 km,
#: larger than any campus. Beyond it a value is no position (1e308 m overflows every raster and window)
MAX_COORD_M = 1e5
#: m; the distance one walk may cover, step by step (a day's walking is ~30 km)
MAX_WALK_PATH_M = 1e5
#: rows of an anchors file (known positions; 100,000 anchors need ~350 MB in optimize)
MAX_ANCHORS = 100_000
#: poses (steps) in one walk: a walk is one recording session; 100,000 steps are ~16 hours of walking
MAX_WALK_POSES = 100_000
#: distinct APs (BSSIDs; beacons for BLE) heard on one floor: the optimizer compares pairs of scans over all
#: of them, held dense (site1/B1, the largest real floor here, has 1,358)
MAX_APS = 5_000
#: cells of the per-node fingerprint table (nodes with readings × distinct APs), which the optimizer and
#: the map hold dense: 20 million (160 MB as RSSI + counts). The largest real floor here (MS ILC site1/B1):
#: 2,299 nodes × 1,358 APs = 3.1 million
MAX_FINGERPRINT_CELLS = 20_000_000
#: cells of a radio map's bounding box (its pictures and viewer images are rasters of it): 2 x 2 km at 1 m,
#: 4 x 4 km at the default 2 m
MAX_MAP_RASTER_CELLS = 4_000_000
#: entries of a radio map's dense tables (cells × APs), filled cells included
MAX_MAP_CELLS = 20_000_000
#: scans `localize` takes in one run (~1.5 kB of memory each: ~140 hours of scans every 2 s), and the cells
#: of their table (scans × the map's APs), held dense like the fingerprints
MAX_QUERIES = 250_000
MAX_QUERY_CELLS = 20_000_000
#: bytes a gzip-compressed input file may expand to (a "gzip bomb" expands 1,000-fold); decompress a larger
#: file first: plain files are read as they are
MAX_GUNZIP_BYTES = 128 * 2**20
#: cells (rows × columns) of a Parquet input table, known from its footer before anything is decoded (a
#: few KB of run-length-encoded values can decode to GBs): ~5 million rows of a six-column table
MAX_PARQUET_CELLS = 32_000_000
#: bytes of one trace file (MS ILC, IPIN), read whole (~2.5 hours of 50 Hz IMU): the largest published trace
#: has 4 MB, and a trace at this limit needs at most ~700 MB
MAX_TRACE_BYTES = 96 * 2**20
#: bytes of a floor plan file (a detailed mall floor's GeoJSON is a few MB)
MAX_PLAN_BYTES = 64 * 2**20
#: vertices of one floor plan: the MS ILC floors' plans have 1,000-6,000
MAX_PLAN_VERTICES = 100_000
#: m; the largest side of a floor plan's bounding box (the largest buildings are ~1 km long)
MAX_PLAN_SIZE_M = 2_000.0
#: nesting depth of a JSON file rmbuild reads (floor plans, floor_info.json, venue.json): GeoJSON needs 6
MAX_JSON_DEPTH = 64
#: bytes of a config file (or a venues file): a config file is a few kB; a larger file is not read into memory
MAX_CONFIG_BYTES = 1 << 20
#: venues in one venues file (`build --venues`)
MAX_VENUES = 10_000
#: bytes of an MS ILC floor's floor_info.json (a few dozen bytes: the floor's width and height)
MAX_FLOOR_INFO_BYTES = 1 << 20
#: bytes of truth/venue.json (simulate writes a few kB)
MAX_VENUE_BYTES = 64 * 2**20
#: bytes of a floor plan's image file (a scan or drawing of the floor), refused before it is read
MAX_IMAGE_BYTES = 256 * 2**20
#: pixels of a floor plan's image, refused before it is decoded (bounded memory: ~400 MB as RGBA)
MAX_IMAGE_PIXELS = 100_000_000
#: bytes of one MS ILC trace line (the longest line of the published traces has 134 bytes, an SSID at most 32):
#: it bounds the parsers' memory, which would otherwise grow with the longest line times the row count
MAX_TRACE_LINE_BYTES = 4096
