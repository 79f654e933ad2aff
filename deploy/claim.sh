# Sourced by deploy/campaign.sh (and its test, tests/tests/campaign.rs): how lanes share the campaign's slices.
# A slice is claimed by a lock directory named after its text, in $claims (set by the caller), holding the lane's
# pid and put in place by one atomic rename; `touch "$(lock_of SLICE)/done"` marks it ended well. A lock is taken
# while its lane's campaign.sh runs, or once it is done; a lock whose lane no longer runs and is not done (an earlier
# session's, ended mid-run) is taken over by exactly one lane.

lock_of() { echo "$claims/slice-$(printf '%s' "$1" | md5sum | cut -c1-16)"; }

# claim SLICE: 0 if this lane now holds SLICE, 1 if another lane has it or it is done.
claim() {
  local lock tmp="$claims/.claim-$$" pid
  lock=$(lock_of "$1")
  mkdir -p "$claims"
  rm -rf "$tmp" && mkdir "$tmp" && echo $$ > "$tmp/pid"
  until mv -T "$tmp" "$lock" 2>/dev/null; do
    pid=$(cat "$lock/pid" 2>/dev/null || true)
    # Its lane still runs, or ended it (done is written before its lane goes on): taken.
    if { [ -n "$pid" ] && ps -o args= -p "$pid" 2>/dev/null | grep -q campaign.sh; } || [ -e "$lock/done" ]; then
      rm -rf "$tmp"
      return 1
    fi
    # Stale: one lane wins this rename, the others see its claim on the next turn.
    mv -T "$lock" "$claims/.stale-$$" 2>/dev/null && rm -rf "$claims/.stale-$$"
  done
}
