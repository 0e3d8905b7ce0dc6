# A throwaway PostgreSQL 15 server for a test (sourced): initdb and pg_ctl on a unix socket in
# a temp folder, no TCP port. As root, the server runs as the postgres user (PostgreSQL refuses
# to run as root). If it cannot start, the test fails saying why: it is never skipped.
PG_BIN=${PG_BIN:-/usr/lib/postgresql/15/bin}

pg_as() {
  if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}

# pg_start DIR: initdb DIR/pg and start it with its socket in DIR; sets PGURI.
pg_start() {
  local d=$1
  if [ ! -x "$PG_BIN/initdb" ] || [ ! -x "$PG_BIN/pg_ctl" ]; then
    echo "FAIL: PostgreSQL 15 server binaries not found in $PG_BIN (Debian package postgresql; scripts/setup --test installs it)" >&2
    return 1
  fi
  if [ "$(id -u)" = 0 ] && ! id postgres >/dev/null 2>&1; then
    echo "FAIL: running as root and there is no postgres user to run the server as (Debian's postgresql package creates it)" >&2
    return 1
  fi
  chmod 777 "$d"  # the postgres user writes its data folder, socket and log here
  if ! pg_as "$PG_BIN/initdb" -D "$d/pg" -U postgres -A trust --no-sync -E UTF8 > "$d/initdb.log" 2>&1; then
    cat "$d/initdb.log" >&2
    echo "FAIL: initdb failed (above)" >&2
    return 1
  fi
  PGURI="postgresql:///postgres?host=$d&user=postgres"
  pg_resume "$d"
}

# pg_resume DIR: start the server again (after pg_halt).
pg_resume() {
  local d=$1
  if ! pg_as "$PG_BIN/pg_ctl" -D "$d/pg" -l "$d/pg.log" -w -t 60 -o "-c listen_addresses='' -k $d -c fsync=off" start > /dev/null; then
    cat "$d/pg.log" >&2
    echo "FAIL: PostgreSQL did not start (its log is above)" >&2
    return 1
  fi
}

# pg_halt DIR: stop it at once (an outage; and the cleanup). Quiet when it is not running.
pg_halt() {
  [ -f "$1/pg/postmaster.pid" ] || return 0
  pg_as "$PG_BIN/pg_ctl" -D "$1/pg" -m immediate -w stop > /dev/null 2>&1 || true
}

pg_sql() {  # pg_sql "SELECT ...": one value per line, unaligned
  psql "$PGURI" -XAtq -c "$1"
}
