#!/bin/sh
# H-local24: wait for the lead's test suite to finish, then sanity (seeds 7-8) and the judgement (19-22), one job at a time.
cd "$(dirname "$0")/../../../../.." || exit 1
D=docs/results/issue24/session24/local
while ! grep -q rc= /tmp/s24/suite.log; do sleep 15; done
echo "suite done $(date -u +%T)"
echo "sanity $(date -u +%T)"; sh $D/run_sanity.sh
sh $D/run_judge.sh
