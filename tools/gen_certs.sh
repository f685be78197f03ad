#!/usr/bin/env bash
# Certificates for PolarTrack's Zenoh TLS / mTLS transport (BusConfig.tls):
#   tools/gen_certs.sh OUT_DIR [HOST ...] [--client NAME ...]
# writes OUT_DIR/ca.pem (+ ca.key), OUT_DIR/router.pem + router.key (the router's, valid for
# localhost, 127.0.0.1 and every HOST given, e.g. zenoh-router for compose), and for every
# --client NAME a client certificate OUT_DIR/NAME.pem + NAME.key whose common name is NAME (what
# Zenoh's access-control rules match, `cert_common_names`), and OUT_DIR/ids.json: a random
# sender id per client ({NAME: id}, what `--ids` gives a service; every message carries it).
# ECDSA P-256, valid 825 days. The compose deployment's set (compose.yaml):
#   tools/gen_certs.sh deploy/certs zenoh-router --client ingest --client detector \
#     --client tracker --client recorder --client viewer
set -euo pipefail
out=${1:?usage: tools/gen_certs.sh OUT_DIR [HOST ...] [--client NAME ...]}
shift
hosts=(localhost) clients=()
while (($#)); do
  if [[ $1 == --client ]]; then clients+=("${2:?--client needs a name}"); shift 2; else hosts+=("$1"); shift; fi
done
mkdir -p "$out"
cd "$out"
key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }
key ca.key
openssl req -x509 -new -key ca.key -sha256 -days 825 -subj "/CN=polartrack-ca" -out ca.pem \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign"
san="IP:127.0.0.1"
for h in "${hosts[@]}"; do san+=",DNS:$h"; done
sign() {  # name cn ext
  key "$1.key"
  openssl req -new -key "$1.key" -subj "/CN=$2" -out "$1.csr"
  printf '%s\n' "$3" > "$1.ext"
  openssl x509 -req -in "$1.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days 825 -sha256 \
    -extfile "$1.ext" -out "$1.pem" 2>/dev/null
  rm -f "$1.csr" "$1.ext"
}
sign router polartrack-router "subjectAltName=$san
extendedKeyUsage=serverAuth,clientAuth"
for c in "${clients[@]}"; do
  sign "$c" "$c" "subjectAltName=DNS:$c
extendedKeyUsage=clientAuth"
done
if ((${#clients[@]})); then
  {
    printf '{'
    sep=""
    for c in "${clients[@]}"; do printf '%s"%s": "%s"' "$sep" "$c" "$(openssl rand -hex 8)"; sep=", "; done
    printf '}\n'
  } > ids.json
  chmod 644 ids.json
fi
chmod 600 ./*.key
echo "certificates in $out: ca.pem, router.pem/key${clients[*]:+, }${clients[*]/%/.pem/key}${clients[*]:+, ids.json}"
