#!/usr/bin/env bash
# Regenerate the plots under docs/images from the examples (run from the repository root,
# with mechdsl installed: .venv/bin/mechdsl or mechdsl on the PATH).
set -euo pipefail
cd "$(dirname "$0")/.."
M=${MECHDSL:-$( [ -x .venv/bin/mechdsl ] && echo .venv/bin/mechdsl || echo mechdsl )}
out=docs/images
for name in slider_crank fourbar rod_sweep scotch_yoke planetary rack_pinion cam_flat \
            cam_roller fourbar_coupler; do
    "$M" run "examples/$name.mech" -q -o /dev/null --plot "$out/$name.png"
done
for t1 in 0.5 1 2; do
    "$M" run examples/start_from_rest.mech --set "t1=$t1" -q -o /dev/null \
        --plot "$out/start_from_rest_t1_$t1.png"
done
"$M" run examples/plugins/curve_slot/curve_slot.mech -q -o /dev/null --plot "$out/curve_slot.png"
# the pictures of the mechanism itself: an animation, a coupler-curve figure and a sweep
"$M" run examples/slider_crank.mech -q -o /dev/null --trace crank.B --animate "$out/slider_crank.gif" \
    --frames 50 --t1 0.5 --labels
# the seed paper's study (section VII): three run-up times by four rods, twelve variants
"$M" run examples/rod_sweep.mech -q -o /dev/null --sweep l=3.5,2.5,2.2,2.1 --sweep t1=0.5,1,1.5 \
    --step 0.002 --plot "$out/rod_ramp_sweep.png"
"$M" run examples/fourbar.mech -q -o /dev/null --snapshot "$out/fourbar_curve.png" --at 0,0.2,0.4,0.6,0.8
# the redundant crank through the parallelogram's singular positions; the offset stroke at
# its optimum, over a revolution
"$M" run examples/parallelogram.mech -q -o /dev/null --through-singular --plot "$out/parallelogram.png"
# (the file's output is the stroke, one value: drawn from a copy that writes the histories)
tmp=$(mktemp -d)
sed 's/^output .*/output slider.x/' examples/offset_stroke.mech > "$tmp/offset_stroke.mech"
"$M" run "$tmp/offset_stroke.mech" -q -o /dev/null --set e=0.958 \
    --snapshot "$out/offset_stroke.png" --at 0,0.25,0.5,0.75 --trace rod.C --labels
rm -r "$tmp"
# centrodes: the elliptic trammel's Cardan circles
"$M" run examples/trammel.mech -q -o /dev/null --snapshot "$out/trammel_centrodes.png" --at 0.1,0.5,0.9 --labels
# a sweep: each variant in its colour, named in the legend, with its own supports
"$M" run examples/fourbar.mech -q -o /dev/null --sweep d=3.8,4.2 --snapshot "$out/fourbar_sweep.png" \
    --at 0,0.5
# forward dynamics: Andrews' squeezing mechanism, its angles and the mechanism at four instants
"$M" run examples/andrews.mech -q -o /dev/null --plot "$out/andrews.png"
"$M" run examples/andrews.mech -q -o /dev/null --trace triangle.D --snapshot "$out/andrews_snapshot.png" \
    --at 0,0.01,0.02,0.03
# a design study: the brute-force sweep's objective and the optimum of mechdsl optimize
P=${PYTHON:-$( [ -x .venv/bin/python ] && echo .venv/bin/python || echo python3 )}
"$P" examples/coupler_synthesis_figure.py "$out/coupler_synthesis.png"
