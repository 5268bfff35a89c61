#!/usr/bin/env bash
# Pictures for docs/snowflakes3d.md.
#   scripts/gg3d_gallery.sh [build/bin/frostvdb]          every preset at one small size, the built-in
#                                                         preview: docs/images/gg3d/<preset>.png
#   scripts/gg3d_gallery.sh --blender [build/bin/frostvdb] the same, rendered with Blender instead
#   scripts/gg3d_gallery.sh --scenes [build/bin/frostvdb] the family scenes (scenes/gg3d_*.toml) rendered
#                                                         with Blender (scripts/render_vdb_blender.py;
#                                                         optional package): docs/images/gg3d_<scene>.png
#                                                         (the two vapour-reservoir scenes, sandwich plate
#                                                         and capped column, take minutes each)
# Each prints a table row per run: wall time and peak memory of the frostvdb run (and of the render).
set -euo pipefail
mode=presets
render=preview
if [ "${1:-}" = "--scenes" ]; then mode=scenes; shift; fi
if [ "${1:-}" = "--blender" ]; then render=blender; shift; fi
bin=${1:-build/bin/frostvdb}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT

if [ "$mode" = scenes ]; then
    command -v blender > /dev/null || { echo "gg3d_gallery: blender not found (apt-get install blender)" >&2; exit 2; }
    echo "| scene | run wall s | run peak MiB | Blender wall s | Blender peak MiB |"
    echo "|---|---|---|---|---|"
    for scene in scenes/gg3d_*.toml; do
        name=$(basename "$scene" .toml)
        /usr/bin/time -f "%e %M" -o "$out/time" "$bin" run "$scene" --out "$out/$name" --quiet > /dev/null 2>&1
        read -r sec kb < "$out/time"
        vdb=$(ls "$out/$name"/*.vdb | tail -1)
        case $name in *sandwich*) view=low ;; *column*|*needle*|*star*) view=iso ;; *) view=high ;; esac # flat flakes from higher up, the sandwich edge-on
        /usr/bin/time -f "%e %M" -o "$out/btime" blender -b -P scripts/render_vdb_blender.py -- "$vdb" \
            "docs/images/$name.png" --samples "${SAMPLES:-24}" --res 640x480 --view "$view" > "$out/blender.log" 2>&1 ||
            { cat "$out/blender.log" >&2; exit 1; }
        read -r bsec bkb < "$out/btime"
        echo "| $name | $sec | $((kb / 1024)) | $bsec | $((bkb / 1024)) |"
    done
    exit 0
fi

mkdir -p docs/images/gg3d
cat > "$out/gallery.toml" <<'TOML'
[scene]
name = "gallery"
frames = 1
steps_per_frame = 5000
[domain]
size = [101, 101]
voxel_size = 0.0001
[gravner_griffeath_3d]
domain_radius = 50
layers = 51
[output]
world_scale = 100
TOML
presets=$("$bin" keys --markdown | grep -A3 '^| `preset`' | grep -o 'fig[0-9a-z_]*' | sort -u)
if [ "$render" = blender ]; then
    echo "| preset | picture | run wall s | run peak MiB | Blender wall s | Blender peak MiB |"
    echo "|---|---|---|---|---|---|"
else
    echo "| preset | picture | wall s | peak MiB |"
    echo "|---|---|---|---|"
fi
for p in $presets; do
    /usr/bin/time -f "%e %M" -o "$out/time" "$bin" run "$out/gallery.toml" --out "$out/$p" --quiet \
        --set "gravner_griffeath_3d.preset=\"$p\"" > /dev/null 2>&1
    read -r sec kb < "$out/time"
    pic="![$p](images/gg3d/$p.png)"
    if [ "$render" = blender ]; then
        case $p in *column*|*needle*|*star_with*) view=iso ;; *) view=high ;; esac
        /usr/bin/time -f "%e %M" -o "$out/btime" blender -b -P scripts/render_vdb_blender.py -- \
            "$out/$p/gallery.0001.vdb" "docs/images/gg3d/$p.png" --samples "${SAMPLES:-16}" --res 480x360 \
            --view "$view" > "$out/blender.log" 2>&1 || { cat "$out/blender.log" >&2; exit 1; }
        read -r bsec bkb < "$out/btime"
        echo "| \`$p\` | $pic | $sec | $((kb / 1024)) | $bsec | $((bkb / 1024)) |"
    else
        cp "$out/$p/gallery.0001.png" "docs/images/gg3d/$p.png"
        echo "| \`$p\` | $pic | $sec | $((kb / 1024)) |"
    fi
done
