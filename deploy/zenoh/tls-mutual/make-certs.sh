#!/bin/sh
# make-certs.sh: a test certificate authority and one certificate per Zenoh node, for mutual TLS.
#
#   make-certs.sh OUT_DIR NODE[=SANS] ...
#
# OUT_DIR/ca.pem and OUT_DIR/ca-key.pem are the CA; they are made on the first run and reused
# after, so more nodes can be added later. Each NODE gets OUT_DIR/NODE/cert.pem and key.pem
# (EC P-256, valid DAYS days, default 825). SANS are the subjectAltName entries in openssl's
# syntax, default DNS:NODE; a connecting node checks the name it dials against them, so give
# every name and address others use, e.g.
#
#   make-certs.sh /etc/drona/tls router=DNS:router.lan,IP:10.0.0.1 d1=DNS:d1.lan,IP:10.0.0.11
#
# Every certificate is good for both ends of a link (serverAuth and clientAuth): a router or a
# peer listens with it, a client or a peer presents it when connecting.
#
# This is a test CA. In the field keep ca-key.pem off the drones (sign on one machine, copy
# only ca.pem and the node's own cert.pem and key.pem to each host).
set -eu

if [ "$#" -lt 2 ]; then
    echo "usage: $0 OUT_DIR NODE[=SANS] ..." >&2
    exit 2
fi
command -v openssl >/dev/null 2>&1 || { echo "$0: openssl is not installed" >&2; exit 2; }

out=$1
shift
days=${DAYS:-825}
umask 077
mkdir -p "$out"
chmod 755 "$out"

if [ ! -f "$out/ca.pem" ]; then
    openssl req -x509 -new -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$out/ca-key.pem" -out "$out/ca.pem" -days "$days" -subj "/CN=drona test CA" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
    chmod 644 "$out/ca.pem"
    echo "made CA $out/ca.pem"
fi

for spec in "$@"; do
    name=${spec%%=*}
    sans=DNS:$name
    case $spec in *=*) sans=${spec#*=} ;; esac
    case $name in
        "" | */* | .*) echo "$0: bad node name '$name'" >&2; exit 2 ;;
    esac
    dir=$out/$name
    mkdir -p "$dir"
    chmod 755 "$dir"
    ext=$dir/ext.cnf
    printf '%s\n' \
        "basicConstraints=critical,CA:FALSE" \
        "keyUsage=critical,digitalSignature" \
        "extendedKeyUsage=serverAuth,clientAuth" \
        "subjectAltName=$sans" >"$ext"
    openssl req -new -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$dir/key.pem" -out "$dir/req.csr" -subj "/CN=$name" 2>/dev/null
    openssl x509 -req -in "$dir/req.csr" -CA "$out/ca.pem" -CAkey "$out/ca-key.pem" -CAcreateserial \
        -out "$dir/cert.pem" -days "$days" -sha256 -extfile "$ext" 2>/dev/null
    rm -f "$dir/req.csr" "$ext"
    chmod 644 "$dir/cert.pem"
    echo "made $dir/cert.pem ($sans)"
done
