# Sourced by deploy/campaign.sh (and its test, tests/tests/campaign.rs): how lanes share the campaign's slices.
# A slice is claimed by a lock directory named after its text, in $claims (set by the caller), holding its owner
# (the lane's pid and a token of the lock's own, in one file), put in place by one atomic rename;
# `touch "$(lock_of SLICE)/done"` marks it ended well. A lock is taken while its lane's campaign.sh runs, or once it
# is done; a lock whose lane no longer runs and is not done (an earlier session's, ended mid-run) is taken over by
# exactly one lane.

lock_of() { echo "$claims/slice-$(printf '%s' "$1" | md5sum | cut -c1-16)"; }

# claim SLICE: 0 if this lane now holds SLICE, 1 if another lane has it or it is done.
claim() {
  local lock tmp="$claims/.claim-$$" owner pid token
  lock=$(lock_of "$1")
  mkdir -p "$claims"
  rm -rf "$tmp" && mkdir "$tmp" && echo "$$ $$-$RANDOM$RANDOM-$(date +%s%N)" > "$tmp/owner"
  until mv -T "$tmp" "$lock" 2>/dev/null; do
    # One read, so that pid and token are the same lock's (another lane may put a new lock in place meanwhile);
    # older locks hold their pid alone, in `pid`.
    owner=$(cat "$lock/owner" 2>/dev/null || cat "$lock/pid" 2>/dev/null || true)
    read -r pid token <<< "$owner" || true
    # Neither file: the lock was being replaced between the two reads; look again.
    [ -n "$pid" ] || continue
    # Its lane still runs, or ended it (done is written before its lane goes on): taken.
    if ps -o args= -p "$pid" 2>/dev/null | grep -q campaign.sh || [ -e "$lock/done" ]; then
      rm -rf "$tmp"
      return 1
    fi
    # Stale: moved aside under its own token, a name that outlives it. Of the lanes that saw this lock stale, the
    # first one's rename wins; a later one's finds the name taken (a directory with files in it) and cannot move
    # the lock that the winner has put in its place since. Older locks, without a token, are moved aside under
    # their pid.
    mv -T "$lock" "$lock.stale-${token:-pid$pid}" 2>/dev/null || true
  done
}
