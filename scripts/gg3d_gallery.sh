#!/usr/bin/env bash
# Renders every [gravner_griffeath_3d] preset at one small size for docs/snowflakes3d.md:
# docs/images/gg3d/<preset>.png plus a table row (wall time, peak memory) per preset.
#   scripts/gg3d_gallery.sh [build/bin/frostvdb]
set -euo pipefail
bin=${1:-build/bin/frostvdb}
out=$(mktemp -d)
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
echo "| preset | wall s | peak MiB |"
echo "|---|---|---|"
for p in $presets; do
    /usr/bin/time -f "%e %M" -o "$out/time" "$bin" run "$out/gallery.toml" --out "$out/$p" --quiet \
        --set "gravner_griffeath_3d.preset=\"$p\"" > /dev/null 2>&1
    read -r sec kb < "$out/time"
    cp "$out/$p/gallery.0001.png" "docs/images/gg3d/$p.png"
    echo "| $p | $sec | $((kb / 1024)) |"
done
rm -rf "$out"
