#!/usr/bin/env bash
# Regenerates the TEST-ONLY certificates of tests/tests/access_control.rs's TLS test (never use
# them on a robot: their private keys are public). A trusted CA signs the node's certificate
# (localhost, 127.0.0.1) and a client's; a second, untrusted CA signs an intruder's. ECDSA P-256,
# valid for 100 years so the committed files do not expire under CI.
set -euo pipefail
cd "$(dirname "$0")"
DAYS=36500
ca() {  # name subject
  openssl ecparam -name prime256v1 -genkey -noout | openssl pkcs8 -topk8 -nocrypt -out "$1.key"
  openssl req -x509 -new -key "$1.key" -sha256 -days "$DAYS" -subj "/CN=$2" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$1.pem"
}
leaf() {  # name ca subject extendedKeyUsage [subjectAltName]
  openssl ecparam -name prime256v1 -genkey -noout | openssl pkcs8 -topk8 -nocrypt -out "$1.key"
  openssl req -new -key "$1.key" -subj "/CN=$3" -out "$1.csr"
  {
    echo "basicConstraints=critical,CA:FALSE"
    echo "keyUsage=critical,digitalSignature"
    echo "extendedKeyUsage=$4"
    [[ -n "${5:-}" ]] && echo "subjectAltName=$5"
  } >"$1.ext"
  openssl x509 -req -in "$1.csr" -CA "$2.pem" -CAkey "$2.key" -CAcreateserial -sha256 \
    -days "$DAYS" -extfile "$1.ext" -out "$1.pem"
  rm -f "$1.csr" "$1.ext"
}
ca ca "groupforward test CA"
ca rogue_ca "untrusted test CA"
leaf node ca "groupforward node" serverAuth "DNS:localhost,IP:127.0.0.1"
leaf client ca "operator" clientAuth
leaf intruder rogue_ca "intruder" clientAuth
rm -f ./*.srl ca.key rogue_ca.key
