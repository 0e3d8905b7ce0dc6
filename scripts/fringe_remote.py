#!/usr/bin/env python3
"""Start a fringe run over HTTP, wait for it, print the verdict; exit 0 PASS/MARGINAL, 1 FAIL,
2 ERROR/ABORTED or any problem. Standard library only.

  scripts/fringe_remote.py http://127.0.0.1:8080 fig10c-loopback --token-file ~/.local/share/fringe/token
  scripts/fringe_remote.py URL --scenario my-scenario.json --junit out.xml
"""
import argparse
import json
import os
import sys
import time
import urllib.error
import urllib.request


def call(base, path, token=None, body=None, raw=False):
    req = urllib.request.Request(base.rstrip('/') + '/api/v1/' + path, method='POST' if body is not None else 'GET',
                                 data=None if body is None else json.dumps(body).encode())
    if body is not None:
        req.add_header('Content-Type', 'application/json')
    if token:
        req.add_header('Authorization', 'Bearer ' + token)
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            data = r.read()
            return data if raw else json.loads(data)
    except urllib.error.HTTPError as e:
        err = json.loads(e.read() or b'{}').get('error', {})
        field = f" ({err['field']})" if err.get('field') else ''
        sys.exit(f"fringe: HTTP {e.code} {err.get('code', '')}: {err.get('message', '')}{field}")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('url')
    p.add_argument('fixture', nargs='?', help='fixture name (GET /api/v1/fixtures)')
    p.add_argument('--scenario', help='scenario JSON file to send instead of a fixture')
    p.add_argument('--seed', type=int)
    p.add_argument('--token-file', default=os.path.join(os.environ.get('FRINGE_DATA', os.path.expanduser('~/.local/share/fringe')), 'token'))
    p.add_argument('--junit', help='write the JUnit XML report here')
    p.add_argument('--timeout', type=float, default=3600, help='seconds to wait for the run')
    a = p.parse_args()
    if bool(a.fixture) == bool(a.scenario):
        p.error('give a fixture name or --scenario FILE')
    token = open(a.token_file).read().strip()
    body = {'fixture': a.fixture} if a.fixture else {'scenario': json.load(open(a.scenario))}
    if a.seed is not None:
        body['seed'] = a.seed
    run_id = call(a.url, 'runs', token, body)['id']
    print(f'run {run_id} queued', file=sys.stderr)
    deadline = time.monotonic() + a.timeout
    while True:
        run = call(a.url, f'runs/{run_id}', token)
        if run['status'] not in ('queued', 'running'):
            break
        if time.monotonic() > deadline:
            call(a.url, f'runs/{run_id}/cancel', token, {})
            sys.exit(f'fringe: run {run_id} still {run["status"]} after {a.timeout} s; cancelled')
        time.sleep(0.2)
    if a.junit and run['status'] != 'interrupted':
        open(a.junit, 'wb').write(call(a.url, f'runs/{run_id}/report.xml', token, raw=True))
    print(f"run {run_id}: {run['scenario']} {run['verdict']} ({run['status']})" + (f": {run['error']}" if run.get('error') else ''))
    sys.exit({'PASS': 0, 'MARGINAL': 0, 'FAIL': 1}.get(run['verdict'], 2))


if __name__ == '__main__':
    main()
