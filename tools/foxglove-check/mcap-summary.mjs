// Reads an MCAP file's summary section (no dependencies): topics, schema names, message counts
// and the time range, from the Channel, Schema and Statistics records the footer points to.
import fs from "node:fs";

const MAGIC = Buffer.from([0x89, 0x4d, 0x43, 0x41, 0x50, 0x30, 0x0d, 0x0a]);

export function readMcapSummary(file) {
  const fd = fs.openSync(file, "r");
  try {
    const size = fs.fstatSync(fd).size;
    const read = (pos, len) => {
      const buf = Buffer.alloc(len);
      fs.readSync(fd, buf, 0, len, pos);
      return buf;
    };
    if (size < 8 + 29 + 8 || !read(0, 8).equals(MAGIC) || !read(size - 8, 8).equals(MAGIC)) {
      throw new Error(`${file}: not a complete MCAP file (magic missing)`);
    }
    const footer = read(size - 8 - 29, 29);
    if (footer[0] !== 0x02) { throw new Error(`${file}: no footer record`); }
    const summaryStart = Number(footer.readBigUInt64LE(9));
    const summaryOffsetStart = Number(footer.readBigUInt64LE(17));
    if (summaryStart === 0) { throw new Error(`${file}: no summary section`); }
    const summaryEnd = summaryOffsetStart !== 0 ? summaryOffsetStart : size - 8 - 29;
    const buf = read(summaryStart, summaryEnd - summaryStart);
    const schemas = new Map();
    const channels = new Map();
    let stats;
    let pos = 0;
    const str = (b, p) => { const n = b.readUInt32LE(p); return [b.toString("utf8", p + 4, p + 4 + n), p + 4 + n]; };
    while (pos + 9 <= buf.length) {
      const op = buf[pos];
      const len = Number(buf.readBigUInt64LE(pos + 1));
      const body = buf.subarray(pos + 9, pos + 9 + len);
      pos += 9 + len;
      if (op === 0x03) { // Schema: id u16, name, encoding, data
        const [name] = str(body, 2);
        schemas.set(body.readUInt16LE(0), name);
      } else if (op === 0x04) { // Channel: id u16, schema_id u16, topic, ...
        const [topic] = str(body, 4);
        channels.set(body.readUInt16LE(0), { topic, schemaId: body.readUInt16LE(2) });
      } else if (op === 0x0b) { // Statistics
        let p = 0;
        const messageCount = Number(body.readBigUInt64LE(p)); p += 8;
        p += 2 + 4 + 4 + 4 + 4; // schema, channel, attachment, metadata, chunk counts
        const start = body.readBigUInt64LE(p); p += 8;
        const end = body.readBigUInt64LE(p); p += 8;
        const mapLen = body.readUInt32LE(p); p += 4;
        const counts = new Map();
        for (const stop = p + mapLen; p < stop; p += 10) {
          counts.set(body.readUInt16LE(p), Number(body.readBigUInt64LE(p + 2)));
        }
        stats = { messageCount, startNs: start, endNs: end, counts };
      }
    }
    if (!stats) { throw new Error(`${file}: no Statistics record in the summary`); }
    const topics = new Map();
    for (const [id, ch] of channels) {
      const t = topics.get(ch.topic) ?? { schemaName: schemas.get(ch.schemaId), count: 0 };
      t.count += stats.counts.get(id) ?? 0;
      topics.set(ch.topic, t);
    }
    return { size, messageCount: stats.messageCount, startNs: stats.startNs, endNs: stats.endNs, topics };
  } finally {
    fs.closeSync(fd);
  }
}

/** RFC 3339 with nanoseconds, as Studio's `time=` URL parameter takes it. */
export function nsToRfc3339(ns) {
  const sec = ns / 1000000000n;
  const nsec = ns % 1000000000n;
  const iso = new Date(Number(sec) * 1000).toISOString().replace(/\.\d+Z$/, "");
  return `${iso}.${nsec.toString().padStart(9, "0")}Z`;
}
