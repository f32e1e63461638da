#!/bin/bash
# How docs/measured/h200/ was made: `bash run.sh` on a lent GPU machine (NVIDIA H200, 16 cores, torch 2.11+cu130,
# Python 3.12), from the repository root, with .dev/ holding Python 3.12 wheels of what that image lacks
# (open3d-cpu 0.19 without its GUI resources, gymnasium, pydantic, plyfile, rosbags and their needs) and
# the X11 / GL client libraries open3d links (Debian packages, unpacked under /tmp/gl).
# GPU-machine check: CUDA tests, then `calnav bench` section by section (merged into $OUT/bench.json
# after each, so a deadline loses only the section in flight).
set -u
export PYTHONUNBUFFERED=1
T0=$SECONDS
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .dev/whl/*.whl || exit 1
tar xJf .dev/o3d.tar.xz -C /tmp/site || exit 1
# open3d.visualization imports plotly (absent there, unused by calnav): make those imports optional
python3 - <<'PY'
from pathlib import Path
p = Path("/tmp/site/open3d/visualization/__init__.py"); s = p.read_text()
for line in ("from .draw_plotly import draw_plotly\n", "from .draw_plotly import draw_plotly_server\n", "from .to_mitsuba import to_mitsuba\n"):
    s = s.replace(line, "try:\n    " + line + "except ImportError:\n    pass\n")
p.write_text(s)
PY
mkdir -p /tmp/gl && for f in .dev/deb/*.deb; do dpkg -x "$f" /tmp/gl; done
export LD_LIBRARY_PATH=/tmp/gl/usr/lib/x86_64-linux-gnu:/tmp/gl/lib/x86_64-linux-gnu:${LD_LIBRARY_PATH:-}
export PYTHONPATH=/tmp/site:$PWD CALNAV_CACHE=/tmp/cache
mkdir -p /tmp/cache/scenes && cp .dev/scenes/* /tmp/cache/scenes/
echo "setup: $((SECONDS-T0)) s"
{ nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc; lscpu | grep "Model name";
  python3 -c "import sys,torch,numpy,open3d; print(sys.version.split()[0], torch.__version__, numpy.__version__, open3d.__version__, torch.cuda.get_device_name(0))"; } 2>&1 | tee $OUT/env.txt
timeout 150 python3 -m pytest -q -p no:cacheprovider tests/agent/test_segmenters_cuda.py tests/agent/test_segmenters.py 2>&1 | tee $OUT/cuda_tests.log | tail -15
echo "tests done: $((SECONDS-T0)) s"
mkdir -p /tmp/b
for sec in segmenter env fusion agent adapter start_pose scan sequence backends; do
  left=$((${DEADLINE:-420} - (SECONDS-T0)))
  if [ $left -lt 20 ]; then echo "skipped $sec (deadline)" | tee -a $OUT/bench.log; continue; fi
  timeout $left python3 -m calnav bench --only $sec --output /tmp/b/$sec.json >> $OUT/bench.log 2>&1 || echo "section $sec: exit $?" | tee -a $OUT/bench.log
  echo "bench $sec done: $((SECONDS-T0)) s" | tee -a $OUT/bench.log
  python3 -c "import json,glob; d={}; [d.update(json.load(open(f))) for f in sorted(glob.glob('/tmp/b/*.json')) if not f.endswith('manifest.json')]; json.dump(d, open('$OUT/bench.json','w'), indent=1, sort_keys=True)"
done
cp /tmp/b/segmenter.manifest.json $OUT/ 2>/dev/null
python3 -c "import json; d=json.load(open('$OUT/bench.json')); [print(f'{k:48s} {v}') for k,v in d.items()]"
