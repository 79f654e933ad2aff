#!/usr/bin/env bash
# deploy/make-certs.sh: a private CA and one certificate per cabc process, for zenoh's mutual TLS (openssl only);
# the folder `[bus.security] certs` of the run configuration names (deploy/SCALE-OUT.md).
#
# Every certificate's subject Common Name is the process's *component name* on the bus, i.e. the same string as in
# `cabc/<run>/alive/<component>` and `cabc/<run>/metrics/<component>`:
#
#   learner                the learner (zenoh router): server + client certificate, SANs for --host
#   actor/<id>             an actor started with `actor --id <id>`
#   eval/<id>              an evaluator started with `actor --id <id> --eval`
#   expert-server/<id>     an expert server started with `expert-server serve --id <id>`
#   observer               read-only tools (zenoh CLI: metrics, liveliness), optional
#   zenohd                 a standalone zenoh router (deploy/SCALE-OUT.md §2), optional, same SANs as the learner
#
# zenoh's access control matches `subjects[].cert_common_names` exactly against that CN (zenoh 1.10.2,
# src/net/routing/interceptor/authorization.rs, SubjectProperty::matches), so the ACL generated from the run
# configuration names these strings. The role prefix keeps roles apart (an evaluator called `actor-0` is not actor-0).
#
# Files (certificates 0644, keys 0600; every key is EC P-256 in PKCS#8, which zenoh's TLS link reads):
#   OUT/ca.pem  OUT/ca.key              the CA (keep ca.key off the worker machines)
#   OUT/<CN>.pem  OUT/<CN>.key          e.g. OUT/learner.pem, OUT/actor/actor-0.key, OUT/expert-server/0.pem
#
# With --passwords (for `[bus.security] mode = "password"`) also OUT/<CN>.password (0600, random, one per process,
# the learner's included) and OUT/passwords, the learner's dictionary `<CN>:<password>` (0600); a password is kept
# once made.
#
# Idempotent: the CA is made once and never replaced; a leaf certificate is kept when it exists, its key matches,
# it verifies against the CA, it has more than 30 days left and (learner, zenohd) its SANs are the ones asked for;
# otherwise it is re-issued with a new key. --force re-issues every leaf named on the command line.
set -euo pipefail

usage() {
  cat <<'EOF'
Usage: make-certs.sh [options] OUT_DIR

Creates (or completes) a private CA and per-role certificates for cabc's zenoh bus with mutual TLS.

Options:
  --host NAME|IP   a name or address the actors use to reach the learner (SAN of its certificate); repeatable.
                   localhost, 127.0.0.1 and ::1 are always included.
  --actors N       actor certificates for actor-0 ... actor-(N-1) (the ids deploy/run-local.sh uses)
  --actor ID       one actor certificate (CN=actor/ID); repeatable
  --eval ID        one evaluator certificate (CN=eval/ID); repeatable; default: eval
  --expert ID      one expert-server certificate (CN=expert-server/ID); repeatable; default: 0
  --observer       a certificate CN=observer for read-only tools (metrics, liveliness)
  --zenohd         a server certificate CN=zenohd for a standalone router (same SANs as the learner)
  --passwords      also a password file per process and the learner's dictionary (mode = "password")
  --days N         validity of the leaf certificates in days (default 825; the CA: 3650)
  --force          re-issue the leaf certificates named (the CA is never replaced: delete OUT_DIR/ca.* by hand)
  -h, --help       this text

Ids: letters, digits, '-', '_' or '.', as for cabc's key chunks.

Example (learner on host-a / 10.0.0.5, 4 actors, one evaluator, two expert servers, the zenoh CLI):
  deploy/make-certs.sh --host host-a --host 10.0.0.5 --actors 4 --eval eval --expert 0 --expert 1 --observer certs/
EOF
}

die() { echo "make-certs: $*" >&2; exit 1; }

command -v openssl >/dev/null || die "openssl not found"

hosts=() actors=() evals=() experts=()
observer=0 zenohd=0 passwords=0 force=0 days=825 out=""
while (($#)); do
  case "$1" in
    --host) (($# >= 2)) || die "--host needs a value"; hosts+=("$2"); shift 2 ;;
    --actors)
      (($# >= 2)) || die "--actors needs a value"
      [[ "$2" =~ ^[0-9]+$ ]] || die "--actors: not a number: $2"
      for ((i = 0; i < $2; i++)); do actors+=("actor-$i"); done
      shift 2 ;;
    --actor) (($# >= 2)) || die "--actor needs a value"; actors+=("$2"); shift 2 ;;
    --eval) (($# >= 2)) || die "--eval needs a value"; evals+=("$2"); shift 2 ;;
    --expert) (($# >= 2)) || die "--expert needs a value"; experts+=("$2"); shift 2 ;;
    --observer) observer=1; shift ;;
    --zenohd) zenohd=1; shift ;;
    --passwords) passwords=1; shift ;;
    --days)
      (($# >= 2)) || die "--days needs a value"
      [[ "$2" =~ ^[1-9][0-9]*$ ]] || die "--days: not a positive number: $2"
      days="$2"; shift 2 ;;
    --force) force=1; shift ;;
    -h | --help) usage; exit 0 ;;
    -*) usage >&2; die "unknown option $1" ;;
    *) [[ -z "$out" ]] || die "one OUT_DIR only (got '$out' and '$1')"; out="$1"; shift ;;
  esac
done
[[ -n "$out" ]] || { usage >&2; exit 2; }
((${#evals[@]})) || evals=(eval)
((${#experts[@]})) || experts=(0)

check_id() { [[ "$1" =~ ^[A-Za-z0-9._-]+$ ]] || die "bad id '$1': use letters, digits, '-', '_' or '.'"; }
for id in "${actors[@]}" "${evals[@]}" "${experts[@]}"; do check_id "$id"; done

# SANs of the server certificates: always the loopback names, then --host (IP or DNS), without duplicates.
san_list=("DNS:localhost" "IP:127.0.0.1" "IP:::1")
for h in "${hosts[@]}"; do
  if [[ "$h" =~ ^[0-9]+\.[0-9]+\.[0-9]+\.[0-9]+$ || "$h" == *:* ]]; then e="IP:$h"; else e="DNS:$h"; fi
  [[ " ${san_list[*]} " == *" $e "* ]] || san_list+=("$e")
done
sans=$(IFS=,; echo "${san_list[*]}")

mkdir -p "$out"
out=$(cd "$out" && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

new_key() { # new_key FILE: an EC P-256 key in PKCS#8, 0600 from the start
  (umask 077 && openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1.tmp" 2>/dev/null)
  mv -f "$1.tmp" "$1"
  chmod 600 "$1"
}

subj_of() { printf '/CN=%s' "${1//\//\\/}"; } # '/' inside the CN is escaped for -subj

# --- the CA -------------------------------------------------------------------------------------------------------
ca_pem="$out/ca.pem" ca_key="$out/ca.key"
if [[ -f "$ca_pem" && -f "$ca_key" ]]; then
  echo "kept   CA            $ca_pem"
elif [[ -f "$ca_pem" || -f "$ca_key" ]]; then
  die "only one of $ca_pem and $ca_key exists: restore the other or delete both to make a new CA"
else
  new_key "$ca_key"
  cat >"$tmp/ca.cnf" <<'EOF'
[req]
distinguished_name = dn
x509_extensions = v3_ca
prompt = no
[dn]
CN = cabc bus CA
[v3_ca]
basicConstraints = critical, CA:TRUE, pathlen:0
keyUsage = critical, keyCertSign, cRLSign
subjectKeyIdentifier = hash
EOF
  openssl req -new -x509 -config "$tmp/ca.cnf" -key "$ca_key" -sha256 -days 3650 \
    -set_serial "0x$(openssl rand -hex 16)" -out "$ca_pem.tmp"
  mv -f "$ca_pem.tmp" "$ca_pem"
  chmod 644 "$ca_pem"
  echo "made   CA            $ca_pem"
fi
chmod 600 "$ca_key"

# --- leaf certificates --------------------------------------------------------------------------------------------
# issue CN KIND: KIND is server (serverAuth+clientAuth, SANs) or client (clientAuth only).
issue() {
  local cn="$1" kind="$2"
  local pem="$out/$cn.pem" key="$out/$cn.key" sanfile="$out/$cn.san"
  mkdir -p "$(dirname "$pem")"
  if ((!force)) && [[ -f "$pem" && -f "$key" ]] \
    && openssl verify -CAfile "$ca_pem" "$pem" >/dev/null 2>&1 \
    && openssl x509 -in "$pem" -noout -checkend 2592000 >/dev/null 2>&1 \
    && [[ "$(openssl x509 -in "$pem" -noout -pubkey)" == "$(openssl pkey -in "$key" -pubout)" ]] \
    && [[ "$(openssl x509 -in "$pem" -noout -subject -nameopt RFC2253)" == "subject=CN=$cn" ]] \
    && { [[ "$kind" == client ]] || [[ -f "$sanfile" && "$(cat "$sanfile")" == "$sans" ]]; }; then
    chmod 600 "$key"
    printf 'kept   %-13s %s\n' "$kind" "$pem"
    return
  fi
  new_key "$key"
  {
    echo "[v3]"
    echo "basicConstraints = critical, CA:FALSE"
    echo "keyUsage = critical, digitalSignature"
    echo "subjectKeyIdentifier = hash"
    echo "authorityKeyIdentifier = keyid"
    if [[ "$kind" == server ]]; then
      echo "extendedKeyUsage = serverAuth, clientAuth"
      echo "subjectAltName = $sans"
    else
      echo "extendedKeyUsage = clientAuth"
    fi
  } >"$tmp/ext.cnf"
  openssl req -new -key "$key" -subj "$(subj_of "$cn")" -out "$tmp/req.csr"
  openssl x509 -req -in "$tmp/req.csr" -CA "$ca_pem" -CAkey "$ca_key" -sha256 -days "$days" \
    -set_serial "0x$(openssl rand -hex 16)" -extfile "$tmp/ext.cnf" -extensions v3 -out "$pem.tmp" 2>/dev/null
  mv -f "$pem.tmp" "$pem"
  chmod 644 "$pem"
  if [[ "$kind" == server ]]; then echo "$sans" >"$sanfile"; chmod 644 "$sanfile"; else rm -f "$sanfile"; fi
  openssl verify -CAfile "$ca_pem" "$pem" >/dev/null || die "$pem does not verify against $ca_pem"
  printf 'made   %-13s %s\n' "$kind" "$pem"
}

# password CN: OUT/<CN>.password (kept once made), and its line in the learner's dictionary OUT/passwords.
password() {
  local file="$out/$1.password"
  if [[ ! -s "$file" ]]; then
    (umask 077 && openssl rand -hex 24 >"$file.tmp")
    mv -f "$file.tmp" "$file"
    printf 'made   %-13s %s\n' password "$file"
  else
    printf 'kept   %-13s %s\n' password "$file"
  fi
  chmod 600 "$file"
  printf '%s:%s\n' "$1" "$(cat "$file")" >>"$tmp/passwords"
}

cns=(learner)
issue learner server
if ((zenohd)); then issue zenohd server; cns+=(zenohd); fi
for id in "${actors[@]}"; do issue "actor/$id" client; cns+=("actor/$id"); done
for id in "${evals[@]}"; do issue "eval/$id" client; cns+=("eval/$id"); done
for id in "${experts[@]}"; do issue "expert-server/$id" client; cns+=("expert-server/$id"); done
if ((observer)); then issue observer client; cns+=(observer); fi
if ((passwords)); then
  : >"$tmp/passwords"
  for cn in "${cns[@]}"; do password "$cn"; done
  # Merge with the dictionary already there (other ids made earlier), one line per CN.
  [[ -f "$out/passwords" ]] && cat "$out/passwords" >>"$tmp/passwords"
  (umask 077 && awk -F: '!seen[$1]++' "$tmp/passwords" >"$out/passwords.tmp")
  mv -f "$out/passwords.tmp" "$out/passwords"
  chmod 600 "$out/passwords"
  echo "dictionary: $out/passwords (the learner's; each process needs only its own <CN>.password)"
fi

echo
echo "CA: $ca_pem (its key $ca_key signs new certificates: keep it on the learner's machine or offline)"
echo "learner SANs: $sans"
echo "Give each machine ca.pem plus the .pem/.key of the processes it runs."
