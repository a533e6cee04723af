#!/usr/bin/env bash
# Makes sure the system GL libraries that MuJoCo's headless rendering needs are
# present (EGL through Mesa, with OSMesa as the fallback). Installs them with apt
# when missing and root; otherwise prints the exact command and fails.
set -euo pipefail
pkgs=(libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0 libosmesa6)
have() { ldconfig -p 2>/dev/null | grep -q "$1"; }
missing=()
have 'libEGL.so.1 ' || missing+=(libegl1)
have 'libEGL_mesa.so.0 ' || missing+=(libegl-mesa0)
have 'libOpenGL.so.0 ' || missing+=(libopengl0)
have 'libOSMesa.so' || missing+=(libosmesa6)
compgen -G "/usr/lib/*/dri/swrast_dri.so" >/dev/null || missing+=(libgl1-mesa-dri)
[ ${#missing[@]} -eq 0 ] && exit 0
if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null; then
    echo "ensure_gl: installing ${pkgs[*]}" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    apt-get install -y -qq --no-install-recommends "${pkgs[@]}" >/dev/null
    exit 0
fi
echo "ensure_gl: MuJoCo rendering needs GL libraries that are missing (${missing[*]})." >&2
echo "ensure_gl: run: sudo apt-get update && sudo apt-get install -y ${pkgs[*]}" >&2
exit 1
