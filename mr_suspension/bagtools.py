"""Rosbag2 bags that survive a crash, and their repair (``mr-suspension bag repair BAG``).

:class:`BagWriter` writes a rosbag2 directory (``metadata.yaml`` plus one ``.mcap`` or ``.db3``
file) so that a killed writer loses at most the data since its last :meth:`BagWriter.flush`:
MCAP with chunks closed and the file flushed (and fsynced) at every flush, sqlite3 in WAL mode
with a commit at every flush; ``metadata.yaml`` is written at open and rewritten atomically
(temporary file, then rename) every ``metadata_period`` and at close, as rosbag2 does.

A bag whose writer was killed has an MCAP file without summary (no index, no footer), which
rosbags and ``ros2 bag`` refuse, and a ``metadata.yaml`` that lags behind. :func:`repair` (the
counterpart of ``ros2 bag reindex``) stream-reads every complete record of such a file, skips a
torn tail, writes a well-formed MCAP in its place (the original is kept as ``<name>.orig``) and
rebuilds ``metadata.yaml`` from the messages; it also rebuilds a missing, empty or corrupt
``metadata.yaml`` of a healthy MCAP or sqlite3 bag and folds a sqlite3 write-ahead log into its
database. Repairing a repaired bag changes nothing. No ROS client library here: the recorder
node uses the writer, the command line the repair.
"""

import os
from pathlib import Path
import shutil
import sqlite3
import threading
import time

from mcap.reader import make_reader
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema
from mcap.stream_reader import breakup_chunk, StreamReader
from mcap.writer import CompressionType, Writer as McapWriter
import yaml

VERSION = 9  # rosbag2 metadata version (Jazzy and later)
SUFFIX = {'mcap': '.mcap', 'sqlite3': '.db3'}
LIBRARY = 'mr_suspension'
CHUNK_BYTES = 4 << 20  # chunks close at a flush, or at this size if a flush is late
SQLITE_SCHEMA = """
CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,
                      metadata TEXT NOT NULL);
CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                    serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
                    type_description_hash TEXT NOT NULL);
CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,
                                 encoding TEXT NOT NULL,
                                 encoded_message_definition TEXT NOT NULL,
                                 type_description_hash TEXT NOT NULL);
CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                      timestamp INTEGER NOT NULL, data BLOB NOT NULL);
CREATE INDEX timestamp_idx ON messages (timestamp ASC);
INSERT INTO schema(schema_version, ros_distro) VALUES (4, 'mr_suspension');
"""


class BagError(ValueError):
    """A bag that cannot be written, read or repaired (one-line message)."""


def metadata(storage, files, topics):
    """Return the rosbag2 ``metadata.yaml`` mapping.

    ``files``: ``[(relative path, start_ns, end_ns, message_count)]``; ``topics``: dicts with
    ``name``, ``type``, ``serialization_format``, ``offered_qos_profiles`` (the serialized
    string stored with the channel), ``type_description_hash`` and ``message_count``.
    """
    def span(start, end, count):
        return (start, end - start) if count else (0, 0)

    count = sum(f[3] for f in files)
    starts = [f[1] for f in files if f[3]]
    ends = [f[2] for f in files if f[3]]
    start, duration = span(min(starts, default=0), max(ends, default=0), count)
    return {'rosbag2_bagfile_information': {
        'version': VERSION,
        'storage_identifier': storage,
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t['name'], 'type': t['type'],
                                'serialization_format': t['serialization_format'],
                                'offered_qos_profiles': _qos_yaml(t['offered_qos_profiles']),
                                'type_description_hash': t['type_description_hash']},
             'message_count': t['message_count']} for t in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f[0] for f in files],
        'files': [{'path': f[0],
                   'starting_time': {'nanoseconds_since_epoch': span(*f[1:])[0]},
                   'duration': {'nanoseconds': span(*f[1:])[1]},
                   'message_count': f[3]} for f in files],
        'custom_data': None,
        'ros_distro': LIBRARY}}


def _qos_yaml(text):
    """Return a stored QoS string in its metadata.yaml form (a list in version 9)."""
    try:
        value = yaml.safe_load(text) if text else []
    except yaml.YAMLError:
        return text
    return value if isinstance(value, list) else text


def metadata_text(meta):
    """``metadata.yaml`` text of a mapping from :func:`metadata`."""
    return yaml.safe_dump(meta, default_flow_style=False, sort_keys=False)


def write_atomic(path, text, sync=True):
    """Write ``text`` to ``path`` via a temporary file and a rename (never half a file)."""
    path = Path(path)
    tmp = path.with_name(path.name + '.tmp')
    with open(tmp, 'w', encoding='utf-8') as fh:
        fh.write(text)
        fh.flush()
        if sync:
            os.fsync(fh.fileno())
    os.replace(tmp, path)


class BagWriter:
    """Write a rosbag2 bag that a killed process leaves recoverable up to its last flush.

    ``add_connection`` then ``write`` (serialized CDR); call :meth:`maybe_flush` often (it
    flushes when ``flush_period`` seconds of wall time or of log time have passed since the last
    flush) and :meth:`close` at the end.
    """

    def __init__(self, path, storage='mcap', flush_period=0.25, metadata_period=2.0,
                 fsync=True):
        if storage not in SUFFIX:
            raise BagError(f'storage must be one of {sorted(SUFFIX)}, got {storage!r}')
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'{self.path} exists; choose a new output')
        self.storage = storage
        self.flush_period = float(flush_period)
        self.metadata_period = float(metadata_period)
        self.fsync = bool(fsync)
        self.path.mkdir(parents=True)
        self.file = self.path / (self.path.name + SUFFIX[storage])
        self.topics = []  # metadata dicts, index = connection id - 1
        self.start = None  # log time range of all messages
        self.end = None
        self.pending_start = None  # first log time since the last flush
        self.flushes = 0
        self.flush_max_s = 0.0  # longest flush (the caller waits for it)
        self.closed = False
        self._sync = None
        if storage == 'mcap':
            self._fh = open(self.file, 'xb')
            self._mcap = McapWriter(self._fh, chunk_size=CHUNK_BYTES,
                                    compression=CompressionType.NONE)
            self._mcap.start(profile='ros2', library=LIBRARY)
            self._schemas = {}
            if self.fsync:  # fsync in a thread of its own: a slow disk does not stall writing
                self._sync = (threading.Event(), [False])
                self._sync_thread = threading.Thread(target=self._sync_loop, daemon=True,
                                                     name='bag_fsync')
                self._sync_thread.start()
        else:
            self._db = sqlite3.connect(str(self.file), isolation_level=None,
                                       check_same_thread=False)
            self._db.execute('PRAGMA journal_mode=WAL')
            # WAL + NORMAL: a commit survives a killed process (not fsynced: no stall on disk)
            self._db.execute('PRAGMA synchronous=NORMAL')
            self._db.executescript(SQLITE_SCHEMA)
            self._db.execute('BEGIN')
        self.last_flush = self.last_metadata = time.monotonic()
        self.write_metadata()

    def add_connection(self, topic, msgtype, msgdef, digest, qos='[]'):
        """Add a topic; return its connection id (``msgdef``: the ros2msg definition text)."""
        encoding = 'ros2idl' if msgdef.startswith('=' * 80 + '\nIDL: ') else 'ros2msg'
        if self.storage == 'mcap':
            if msgtype not in self._schemas:
                self._schemas[msgtype] = self._mcap.register_schema(msgtype, encoding,
                                                                    msgdef.encode())
            cid = self._mcap.register_channel(topic, 'cdr', self._schemas[msgtype],
                                              {'offered_qos_profiles': qos})
        else:
            cid = len(self.topics) + 1
            if msgtype not in {t['type'] for t in self.topics}:
                self._db.execute('INSERT INTO message_definitions (topic_type, encoding, '
                                 'encoded_message_definition, type_description_hash) '
                                 'VALUES(?, ?, ?, ?)', (msgtype, encoding, msgdef, digest))
            self._db.execute('INSERT INTO topics VALUES(?, ?, ?, ?, ?, ?)',
                             (cid, topic, msgtype, 'cdr', qos, digest))
        self.topics.append({'name': topic, 'type': msgtype, 'serialization_format': 'cdr',
                            'offered_qos_profiles': qos, 'type_description_hash': digest,
                            'message_count': 0})
        return cid

    def write(self, cid, timestamp, data):
        """Write one serialized message on connection ``cid`` at log time ``timestamp`` [ns]."""
        if self.storage == 'mcap':
            self._mcap.add_message(cid, timestamp, data, timestamp)
        else:
            self._db.execute('INSERT INTO messages (topic_id, timestamp, data) VALUES(?, ?, ?)',
                             (cid, timestamp, data))
        self.topics[cid - 1]['message_count'] += 1
        if self.start is None:
            self.start = self.end = timestamp
        else:
            self.start = min(self.start, timestamp)
            self.end = max(self.end, timestamp)
        if self.pending_start is None:
            self.pending_start = timestamp
        elif timestamp - self.pending_start >= self.flush_period * 1e9:
            self.flush()

    @property
    def count(self):
        """Messages written so far."""
        return sum(t['message_count'] for t in self.topics)

    def maybe_flush(self, now=None):
        """Flush if ``flush_period`` has passed since the last flush; return True if it did."""
        now = time.monotonic() if now is None else now
        if now - self.last_flush < self.flush_period or self.closed:
            return False
        self.flush(now)
        return True

    def flush(self, now=None):
        """Make everything written so far durable; rewrite metadata.yaml when it is due.

        MCAP: the chunk in progress is closed and handed to the operating system (a killed
        process loses nothing after this), then fsynced by a background thread (survives a
        power loss too). sqlite3: a commit.
        """
        now = time.monotonic() if now is None else now
        t0 = time.perf_counter()
        self.last_flush = now
        if self.pending_start is not None:
            if self.storage == 'mcap':
                self._mcap.flush()  # closes the chunk in progress and flushes the stream
                if self._sync is not None:
                    self._sync[0].set()
            else:
                self._db.execute('COMMIT')
                self._db.execute('BEGIN')
            self.pending_start = None
            self.flushes += 1
        if now - self.last_metadata >= self.metadata_period:
            self.write_metadata()
        self.flush_max_s = max(self.flush_max_s, time.perf_counter() - t0)

    def _sync_loop(self):
        wanted, stop = self._sync
        fd = self._fh.fileno()
        while True:
            wanted.wait()
            wanted.clear()
            if stop[0]:
                return
            try:
                os.fsync(fd)
            except OSError:
                return

    def write_metadata(self):
        """Rewrite ``metadata.yaml`` (atomically) with the counts and times so far.

        Not fsynced (an fsync took up to 0.3 s on a busy disk, in the writer's thread): a
        killed process leaves it in the page cache, and ``repair`` rebuilds it after a power
        loss. The one written at close is fsynced.
        """
        self.last_metadata = time.monotonic()
        start = self.start if self.start is not None else 0
        end = self.end if self.end is not None else 0
        meta = metadata(self.storage, [(self.file.name, start, end, self.count)], self.topics)
        write_atomic(self.path / 'metadata.yaml', metadata_text(meta), sync=False)

    def close(self):
        """Finish the file (MCAP summary; sqlite3 commit and checkpoint) and metadata.yaml."""
        if self.closed:
            return
        self.closed = True
        start = self.start if self.start is not None else 0
        end = self.end if self.end is not None else 0
        meta = metadata(self.storage, [(self.file.name, start, end, self.count)], self.topics)
        info = yaml.safe_dump(meta['rosbag2_bagfile_information'], sort_keys=False)
        if self.storage == 'mcap':
            if self._sync is not None:
                self._sync[1][0] = True
                self._sync[0].set()
                self._sync_thread.join()
            self._mcap.add_metadata('rosbag2', {'serialized_metadata': info})
            self._mcap.finish()
            self._fh.flush()
            if self.fsync:
                os.fsync(self._fh.fileno())
            self._fh.close()
        else:
            self._db.execute('INSERT INTO metadata(metadata_version, metadata) VALUES(?, ?)',
                             (VERSION, info))
            self._db.execute('COMMIT')
            self._db.execute('PRAGMA wal_checkpoint(TRUNCATE)')
            self._db.execute('PRAGMA journal_mode=DELETE')  # one self-contained file
            self._db.close()
        write_atomic(self.path / 'metadata.yaml', metadata_text(meta), self.fsync)


# --- repair -----------------------------------------------------------------------------------


def _stats():
    return {'count': 0, 'start': None, 'end': None}


def _count(stats, log_time):
    stats['count'] += 1
    stats['start'] = log_time if stats['start'] is None else min(stats['start'], log_time)
    stats['end'] = log_time if stats['end'] is None else max(stats['end'], log_time)


def mcap_summary(path):
    """Return the summary of a well-formed (closed) MCAP file, or None if it has none."""
    try:
        with open(path, 'rb') as fh:
            summary = make_reader(fh).get_summary()
    except Exception:  # any damage at the end of the file: no usable summary
        return None
    if summary is None or summary.statistics is None:
        return None
    if summary.statistics.message_count and not summary.chunk_indexes:
        return None  # messages without an index: rosbags cannot read them
    return summary


def salvage_mcap(src, dst):
    """Copy every complete record of the MCAP ``src`` into a new well-formed MCAP ``dst``.

    Reads ``src`` as a stream up to the first record that is cut off or damaged (a torn tail:
    the process was killed while writing it) or its data end; a chunk that fails to unpack is
    skipped. Returns ``(channels, stats, info)``: channels by new id, message statistics by new
    channel id, and ``info`` with ``good_bytes`` (end of the last complete record), ``size``,
    ``chunks`` and ``bad_chunks``.
    """
    info = {'good_bytes': 0, 'size': os.path.getsize(src), 'chunks': 0, 'bad_chunks': 0,
            'error': ''}
    schemas, channels, stats = {}, {}, {}
    schema_map, channel_map = {}, {}
    with open(src, 'rb') as fh, open(dst, 'xb') as out:
        writer = McapWriter(out, chunk_size=CHUNK_BYTES, compression=CompressionType.NONE)
        writer.start(profile='ros2', library=LIBRARY)

        def take(record):
            if isinstance(record, Schema):
                if record.id not in schema_map:
                    schema_map[record.id] = writer.register_schema(record.name,
                                                                   record.encoding, record.data)
                    schemas[record.id] = record
            elif isinstance(record, Channel):
                if record.id not in channel_map:
                    sid = schema_map.get(record.schema_id, 0)
                    cid = writer.register_channel(record.topic, record.message_encoding, sid,
                                                  dict(record.metadata))
                    channel_map[record.id] = cid
                    channels[cid] = (record, schemas.get(record.schema_id))
                    stats[cid] = _stats()
            elif isinstance(record, Message) and record.channel_id in channel_map:
                cid = channel_map[record.channel_id]
                writer.add_message(cid, record.log_time, record.data, record.publish_time,
                                   record.sequence)
                _count(stats[cid], record.log_time)

        records = StreamReader(fh, emit_chunks=True).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception as exc:  # torn or damaged record: everything after it is lost
                info['error'] = f'{type(exc).__name__} {exc}'.strip()
                break
            if isinstance(record, (DataEnd, Footer)):
                info['good_bytes'] = fh.tell()
                break
            if isinstance(record, Chunk):
                try:
                    inner = breakup_chunk(record, validate_crc=True)
                except Exception:
                    info['bad_chunks'] += 1
                    inner = []
                info['chunks'] += 1
                for rec in inner:
                    take(rec)
            else:
                take(record)
            info['good_bytes'] = fh.tell()
        writer.add_metadata('rosbag2', {'serialized_metadata': 'repaired by mr_suspension'})
        writer.finish()
        out.flush()
        os.fsync(out.fileno())
    return channels, stats, info


def _mcap_topics(summary):
    """Topic entries and file statistics of a healthy MCAP from its summary."""
    st = summary.statistics
    topics = []
    for cid, ch in sorted(summary.channels.items()):
        schema = summary.schemas.get(ch.schema_id)
        topics.append({'name': ch.topic, 'type': schema.name if schema else '',
                       'serialization_format': ch.message_encoding,
                       'offered_qos_profiles': ch.metadata.get('offered_qos_profiles', ''),
                       'type_description_hash': '',
                       'message_count': st.channel_message_counts.get(cid, 0)})
    start, end = (st.message_start_time, st.message_end_time) if st.message_count else (0, 0)
    return topics, (start, end, st.message_count)


def _salvaged_topics(channels, stats):
    topics = []
    for cid, (ch, schema) in sorted(channels.items()):
        topics.append({'name': ch.topic, 'type': schema.name if schema else '',
                       'serialization_format': ch.message_encoding,
                       'offered_qos_profiles': ch.metadata.get('offered_qos_profiles', ''),
                       'type_description_hash': '', 'message_count': stats[cid]['count']})
    used = [s for s in stats.values() if s['count']]
    count = sum(s['count'] for s in used)
    start = min((s['start'] for s in used), default=0)
    end = max((s['end'] for s in used), default=0)
    return topics, (start, end, count)


def sqlite_topics(path):
    """Recover a sqlite3 bag in place (WAL folded in, rollback journal applied); read topics."""
    try:
        db = sqlite3.connect(str(path), isolation_level=None)
        try:
            ok = db.execute('PRAGMA quick_check').fetchone()[0]
            if ok != 'ok':
                raise BagError(f'{path}: sqlite3 database damaged ({ok})')
            db.execute('PRAGMA wal_checkpoint(TRUNCATE)')
            db.execute('PRAGMA journal_mode=DELETE')
            cols = [r[1] for r in db.execute('PRAGMA table_info(topics)')]
            if not cols:
                raise BagError(f'{path}: no topics table; not a rosbag2 sqlite3 bag')
            digest = 'type_description_hash' if 'type_description_hash' in cols else "''"
            qos = 'offered_qos_profiles' if 'offered_qos_profiles' in cols else "''"
            rows = db.execute(
                f'SELECT topics.id, name, type, serialization_format, {qos}, {digest}, '
                'count(messages.id), min(messages.timestamp), max(messages.timestamp) '
                'FROM topics LEFT JOIN messages ON topics.id = messages.topic_id '
                'GROUP BY topics.id ORDER BY topics.id').fetchall()
        finally:
            db.close()
    except sqlite3.Error as exc:
        raise BagError(f'{path}: cannot read as a sqlite3 bag: {exc}') from None
    topics = [{'name': r[1], 'type': r[2], 'serialization_format': r[3],
               'offered_qos_profiles': r[4] or '', 'type_description_hash': r[5] or '',
               'message_count': r[6]} for r in rows]
    used = [r for r in rows if r[6]]
    count = sum(r[6] for r in used)
    start = min((r[7] for r in used), default=0)
    end = max((r[8] for r in used), default=0)
    return topics, (start, end, count)


def read_metadata(path):
    """Return the ``rosbag2_bagfile_information`` mapping of a metadata.yaml, or None."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
        info = data['rosbag2_bagfile_information']
        info['relative_file_paths'], info['topics_with_message_count']  # noqa: B018
        return info if isinstance(info, dict) else None
    except Exception:  # missing, empty, not YAML, or not rosbag2 metadata
        return None


def _hashes(old):
    """Type hashes by topic name from an old metadata mapping (kept when rebuilding)."""
    out = {}
    for t in (old or {}).get('topics_with_message_count') or []:
        try:
            out[t['topic_metadata']['name']] = t['topic_metadata']['type_description_hash']
        except (KeyError, TypeError):
            pass
    return out


def _known_hash(msgtype):
    """RIHS01 hash of a message type rosbags knows (``''`` otherwise)."""
    from rosbags.typesys import get_typestore, Stores
    try:
        return get_typestore(Stores.LATEST).hash_rihs01(msgtype)
    except Exception:  # a type the store does not hold
        return ''


def _backup_name(path):
    """``<path>.orig`` or, if that exists, ``<path>.orig1``, ``.orig2``..."""
    cand = path.with_name(path.name + '.orig')
    k = 1
    while cand.exists():
        cand = path.with_name(f'{path.name}.orig{k}')
        k += 1
    return cand


def repair(bag, out=None, log=print):
    """Repair the rosbag2 directory ``bag`` (in place, or into a new directory ``out``).

    Returns a dict with ``bag`` (the repaired directory), ``files`` (per storage file: name,
    state ``ok``/``repaired``, messages, ``lost_bytes``), ``messages``, ``duration_s`` and
    ``metadata`` (``kept`` or ``rebuilt``). ``log`` gets one line per action. Raises
    :class:`BagError` (one line) for anything that is not a bag.
    """
    bag = Path(bag)
    if not bag.exists():
        raise BagError(f'{bag}: no such bag directory')
    if not bag.is_dir():
        raise BagError(f'{bag}: not a directory; give the bag directory (the one holding '
                       'metadata.yaml and the .mcap or .db3 file)')
    mcaps = sorted(p for p in bag.iterdir() if p.suffix == '.mcap' and p.is_file())
    dbs = sorted(p for p in bag.iterdir() if p.suffix == '.db3' and p.is_file())
    if not mcaps and not dbs:
        raise BagError(f'{bag}: no .mcap or .db3 file; not a rosbag2 bag directory')
    if mcaps and dbs:
        raise BagError(f'{bag}: holds both .mcap and .db3 files; one storage per bag')
    storage = 'mcap' if mcaps else 'sqlite3'
    dest = bag
    if out is not None:
        dest = Path(out)
        if dest.exists() and (not dest.is_dir() or any(dest.iterdir())):
            raise BagError(f'{dest}: exists and is not an empty directory')
        try:
            dest.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagError(f'{dest}: cannot create: {exc.strerror}') from None
    old = read_metadata(bag / 'metadata.yaml')
    try:
        result = _repair_files(bag, dest, mcaps or dbs, storage, log)
    except OSError as exc:
        raise BagError(f'{bag}: {exc.strerror or exc}: {exc.filename or ""}'.rstrip(': ')) \
            from None
    hashes = _hashes(old)
    topics, files = [], []
    merged = {}
    for entry in result:
        files.append((entry['name'],) + entry['stats'])
        for t in entry['topics']:
            key = (t['name'], t['type'])
            if key in merged:
                merged[key]['message_count'] += t['message_count']
                continue
            t['type_description_hash'] = (t['type_description_hash'] or hashes.get(t['name'])
                                          or _known_hash(t['type']))
            merged[key] = t
            topics.append(t)
    text = metadata_text(metadata(storage, files, topics))
    meta_path = dest / 'metadata.yaml'
    previous = meta_path.read_text(encoding='utf-8') if meta_path.is_file() else None
    state = 'kept'
    if previous != text:
        if previous is not None and previous.strip():
            shutil.copy2(meta_path, _backup_name(meta_path))
        write_atomic(meta_path, text)
        state = 'rebuilt'
    count = sum(f[3] for f in files)
    start = min((f[1] for f in files if f[3]), default=0)
    end = max((f[2] for f in files if f[3]), default=0)
    duration = (end - start) / 1e9 if count else 0.0
    log(f'{meta_path}: {state} ({len(topics)} topics, {count} messages, {duration:.3f} s)')
    return {'bag': str(dest), 'storage': storage, 'messages': count, 'duration_s': duration,
            'metadata': state,
            'files': [{k: e[k] for k in ('name', 'state', 'lost_bytes')}
                      | {'messages': e['stats'][2]} for e in result]}


def _repair_files(bag, dest, paths, storage, log):
    """Repair or check each storage file; return one dict per file (name, topics, stats...)."""
    result = []
    for path in paths:
        target = dest / path.name
        lost = 0
        if storage == 'sqlite3':
            if dest != bag:
                for extra in ('', '-wal', '-journal'):
                    if Path(str(path) + extra).exists():
                        shutil.copy2(str(path) + extra, str(target) + extra)
            wal = Path(str(target) + '-wal').exists() or Path(str(target) + '-journal').exists()
            tops, stats = sqlite_topics(target)
            state = 'repaired' if wal else 'ok'
            log(f'{target}: {"recovered from its journal" if wal else "ok"}, {stats[2]} '
                'messages')
        else:
            summary = mcap_summary(path)
            if summary is not None:
                tops, stats = _mcap_topics(summary)
                if dest != bag:
                    shutil.copy2(path, target)
                state = 'ok'
                log(f'{target}: ok, {stats[2]} messages')
            else:
                tmp = dest / (path.name + '.repair.tmp')
                if tmp.exists():
                    tmp.unlink()
                channels, mstats, info = salvage_mcap(path, tmp)
                tops, stats = _salvaged_topics(channels, mstats)
                lost = info['size'] - info['good_bytes']
                if dest == bag:
                    backup = _backup_name(path)
                    os.replace(path, backup)
                    kept = f'; original kept as {backup.name}'
                else:
                    kept = ''
                os.replace(tmp, target)
                state = 'repaired'
                span = (stats[1] - stats[0]) / 1e9 if stats[2] else 0.0
                log(f'{target}: no summary (writer did not close it); recovered {stats[2]} '
                    f'messages ({span:.3f} s) from {info["chunks"]} chunks, '
                    f'{lost} bytes of torn tail skipped'
                    + (f', {info["bad_chunks"]} damaged chunks skipped'
                       if info['bad_chunks'] else '') + kept)
        result.append({'name': target.name, 'topics': tops, 'stats': stats, 'state': state,
                       'lost_bytes': lost})
    return result


def cmd_repair(args):
    """``mr-suspension bag repair BAG [--out DIR]``."""
    res = repair(args.bag, args.out)
    print(f'{res["bag"]}: readable, {res["messages"]} messages, {res["duration_s"]:.3f} s')
    return 0


def register(subparsers):
    """Add the ``bag`` command (subcommand ``repair``)."""
    p = subparsers.add_parser('bag', help='rosbag2 bag tools (repair a bag a crash left open)',
                              description='Tools for the rosbag2 bags the recorder writes.')
    sub = p.add_subparsers(dest='bag_command', metavar='SUBCOMMAND')
    sub.required = True
    r = sub.add_parser('repair', help='make a bag readable after a crash (like ros2 bag reindex)',
                       description='Recover every complete message of a bag whose recorder was '
                                   'killed (MCAP without summary, truncated mid-chunk), write a '
                                   'well-formed file in its place (original kept as '
                                   '<name>.orig) and rebuild metadata.yaml; also rebuilds a '
                                   'missing or corrupt metadata.yaml and recovers a sqlite3 bag '
                                   'from its journal. Repairing a healthy bag changes nothing.')
    r.add_argument('bag', help='bag directory (holding the .mcap or .db3 file)')
    r.add_argument('--out', default=None,
                   help='write the repaired bag to this new directory instead (BAG untouched)')
    r.set_defaults(func=cmd_repair)
