# Shell helpers for the test and load scripts (sourced).

# poll_log FILE SED_EXPR [TRIES] [DELAY_S]: wait until `sed -n SED_EXPR FILE` prints something
# and print its first line; return 1 after TRIES polls (default 100, 0.05 s apart). FILE may
# not exist yet: a background job opens its `> FILE` redirection after the fork, so the first
# polls can come before it.
poll_log() {
  local file=$1 expr=$2 tries=${3:-100} delay=${4:-0.05} got
  for _ in $(seq "$tries"); do
    got=$(sed -n "$expr" "$file" 2>/dev/null | head -n 1 || true)
    [ -n "$got" ] && { echo "$got"; return 0; }
    sleep "$delay"
  done
  return 1
}
