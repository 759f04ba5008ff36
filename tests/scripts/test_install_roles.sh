#!/usr/bin/env bash
# scripts/install-deps.sh roles: a render node gets no libtorch, no Slurm and
# no browser; a trainer gets libtorch but no Slurm; `all` (what CI and
# scripts/build.sh install) is the union; an unknown role is an error. Every
# package named is one Debian's archive knows (catches a misspelt name).
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
deps="$root/scripts/install-deps.sh"
fail=0
check() { if ! eval "$2"; then echo "FAIL: $1"; fail=1; fi; }
has() { "$deps" --list $1 | grep -x "$2" >/dev/null; }  # no -q: the lister must not get SIGPIPE

check "render has embree" "has render libembree-dev"
check "render has the status page's http library" "has render libcpp-httplib-dev"
for p in libtorch-dev slurm-wlm munge chromium libgtest-dev openimageio-tools; do
  check "render must not install $p" "! has render $p"
done
check "trainer has libtorch" "has trainer libtorch-dev"
check "trainer must not install slurm" "! has trainer slurm-wlm"
check "cluster has slurm and munge" "has cluster slurm-wlm && has cluster munge"
check "test has chromium and gtest" "has test chromium && has test libgtest-dev"
union=$("$deps" --list render trainer cluster test | sort -u)
check "all is the union of the roles" "[ \"\$(\"$deps\" --list | sort)\" = \"\$union\" ]"
check "no duplicates in a listing" "[ \"\$(\"$deps\" --list all | sort | uniq -d)\" = '' ]"
"$deps" --list nosuchrole >/dev/null 2>&1
check "an unknown role exits 2" "[ $? -eq 2 ]"
if command -v apt-cache >/dev/null; then
  for p in $("$deps" --list all); do
    apt-cache show --no-all-versions "$p" >/dev/null 2>&1 || { echo "FAIL: apt does not know $p"; fail=1; }
  done
fi
[ $fail -eq 0 ] && echo "install-deps roles: ok"
exit $fail
