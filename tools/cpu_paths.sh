#!/usr/bin/env bash
# The non-slow tests under each OpenBLAS kernel x numpy SIMD dispatch (issue 16): a tolerance
# fitted to one CPU shows up here as a failure under another kernel or dispatch path.
#
#   tools/cpu_paths.sh                  # every non-slow test, every configuration (long)
#   tools/cpu_paths.sh -m numerics      # narrowed: pytest arguments are passed through
#   CORES="Haswell Prescott" DISPATCH="on baseline" tools/cpu_paths.sh -m numerics
#
# OPENBLAS_CORETYPE forces OpenBLAS's kernel (numpy's and scipy's bundled OpenBLAS alike);
# NPY_DISABLE_CPU_FEATURES turns numpy's AVX-512 loops off (DISPATCH "avx512-off"; "baseline"
# turns its AVX2/FMA3 loops off too, as the second numerics run of .ci/run does). Exit status 1
# if any configuration failed. A kernel the CPU cannot execute
# is skipped: OpenBLAS does not check, it dies with SIGILL (exit 132) at the first BLAS call.
# A kernel OpenBLAS does not accept as OPENBLAS_CORETYPE ("Core not found", it then keeps the
# one it detects) is skipped too: before each run the kernel in use is read back from both
# OpenBLAS libraries and must be the one asked for. One summary line per configuration.
set -uo pipefail
cd "$(dirname "$0")/.."
python="${PYTHON:-python}"
cores="${CORES:-Haswell SkylakeX SapphireRapids Prescott Zen}"
dispatches="${DISPATCH:-on avx512-off}"
status=0
has_m=0
for arg in "$@"; do [ "$arg" = "-m" ] && has_m=1; done
[ "$has_m" -eq 1 ] || set -- -m "not slow" "$@"

flags=" $(grep -m1 '^flags' /proc/cpuinfo | cut -d: -f2) "
# CPU flags each kernel executes (OpenBLAS kernel/x86_64: Prescott SSE3 = "pni"; Haswell and
# Zen AVX2 + FMA; SkylakeX AVX-512 F/BW/DQ/VL; SapphireRapids adds AVX512-BF16 and AMX)
needs() {
    case "$1" in
        Prescott) echo "pni" ;;
        Haswell|Zen) echo "avx2 fma" ;;
        SkylakeX) echo "avx512f avx512bw avx512dq avx512vl" ;;
        SapphireRapids) echo "avx512f avx512bw avx512dq avx512vl avx512_bf16 amx_bf16" ;;
        *) echo "" ;;
    esac
}
# the name OpenBLAS reports for a forced kernel: Prescott is built as its Katmai alias, Zen
# runs the Haswell kernels in these dynamic-arch builds
reported() {
    case "$1" in
        Prescott) echo "Katmai" ;;
        Zen) echo "Haswell" ;;
        *) echo "$1" ;;
    esac
}
corename='
import ctypes, glob, os, numpy, scipy
names = []
for pkg, sym in ((numpy, "scipy_openblas_get_corename64_"), (scipy, "scipy_openblas_get_corename")):
    for path in glob.glob(os.path.dirname(pkg.__file__) + ".libs/libscipy_openblas*.so"):
        lib = ctypes.CDLL(path)
        if hasattr(lib, sym):
            getattr(lib, sym).restype = ctypes.c_char_p
            names.append(getattr(lib, sym)().decode())
print(" ".join(sorted(set(names))) or "unknown")
'
results="$(mktemp -d)"
trap 'rm -rf "$results"' EXIT
summary=()
for core in $cores; do
    missing=""
    for flag in $(needs "$core"); do
        [[ "$flags" == *" $flag "* ]] || missing="$missing $flag"
    done
    if [ -n "$missing" ]; then
        summary+=("$core: skipped, the CPU lacks$missing (OpenBLAS would die with SIGILL)")
        continue
    fi
    in_use="$(OPENBLAS_CORETYPE="$core" "$python" -c "$corename" 2>/dev/null)"
    if [ "$in_use" != "$(reported "$core")" ]; then
        summary+=("$core: skipped, OPENBLAS_CORETYPE=$core gives kernel '$in_use' (not selectable in this OpenBLAS)")
        continue
    fi
    for dispatch in $dispatches; do
        case "$dispatch" in
            on) disabled="" ;;
            avx512-off) disabled="AVX512_SPR AVX512_ICL X86_V4" ;;
            baseline) disabled="X86_V3 X86_V4 AVX512_ICL AVX512_SPR" ;;
            *) echo "unknown DISPATCH value '$dispatch' (on, avx512-off, baseline)" >&2; exit 2 ;;
        esac
        config="OPENBLAS_CORETYPE=$core (kernel $in_use), numpy dispatch $dispatch"
        xml="$results/$core-$dispatch.xml"
        echo "=== $config"
        OPENBLAS_CORETYPE="$core" NPY_DISABLE_CPU_FEATURES="$disabled" \
            "$python" -m pytest -q -p no:cacheprovider --junitxml="$xml" "$@"
        code=$?
        [ "$code" -eq 0 ] || status=1
        line="$("$python" - "$xml" "$code" <<'PY'
import sys
import xml.etree.ElementTree as ET
path, code = sys.argv[1], int(sys.argv[2])
try:
    cases = ET.parse(path).getroot().iter("testcase")
except (OSError, ET.ParseError):
    print(f"no result (pytest exit {code})")
    sys.exit()
passed, failed, skipped, ids = 0, 0, 0, []
for case in cases:
    kinds = {child.tag for child in case}
    if kinds & {"failure", "error"}:
        failed += 1
        classname = case.get("classname") or ""
        ids.append(f"{classname.replace('.', '/')}.py::{case.get('name')}" if classname
                   else case.get("name"))          # a collection error names the module
    elif "skipped" in kinds:
        skipped += 1
    else:
        passed += 1
tail = f"; failing: {' '.join(ids)}" if ids else ""
print(f"{passed} passed, {failed} failed, {skipped} skipped (pytest exit {code}){tail}")
PY
)"
        summary+=("$config: $line")
    done
done
echo
echo "=== summary ($*)"
printf '%s\n' "${summary[@]}"
exit "$status"
