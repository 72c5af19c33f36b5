// Read one labrunner run log with the official TypeScript MCAP reader, @mcap/core, the way the
// Foxglove app does (McapIndexedReader for a local file with a summary; McapStreamReader
// otherwise), and print what each reader decoded as one JSON object on stdout:
//
//   {"indexed": READ | {"error": "..."}, "stream": READ | {"error": "..."}}
//   READ = {"metadata": {name: {key: value}},
//           "messages": {topic: [[sequence, logTime, {field: value}], ...]},  // in the reader's order
//           "complete": bool,  // stream: the file ended with its footer and magic
//           "byTopic": {topic: [sequences read with that topic alone, the same read in reverse
//                       and turned back]}}  // indexed only
//
// Protobuf payloads are decoded with protobufjs from the schema stored in the file (the
// FileDescriptorSet, as Foxglove decodes them). Numbers are written so that Python reads back the
// very float64 (JavaScript prints the shortest text that round-trips); the values JSON cannot
// hold are strings: "NaN", "Infinity", "-Infinity", "-0". 64-bit integers are strings.
//
// Usage: node read_log.js FILE

"use strict";

const fs = require("node:fs");
const { McapIndexedReader, McapStreamReader } = require("@mcap/core");
const fzstd = require("fzstd");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

const decompressHandlers = {
  zstd: (data, size) => fzstd.decompress(data, new Uint8Array(Number(size))),
};

function plain(value) {
  if (typeof value === "number") {
    if (Number.isNaN(value)) return "NaN";
    if (value === Infinity) return "Infinity";
    if (value === -Infinity) return "-Infinity";
    if (Object.is(value, -0)) return "-0";
    return value;
  }
  if (typeof value === "bigint") return value.toString();
  if (Array.isArray(value)) return value.map(plain);
  if (value !== null && typeof value === "object") {
    const out = {};
    for (const [k, v] of Object.entries(value)) out[k] = plain(v);
    return out;
  }
  return value;
}

class Decoders {
  constructor() {
    this.schemas = new Map(); // schema id → {name, encoding, data}
    this.channels = new Map(); // channel id → {topic, schemaId}
    this.types = new Map(); // schema id → protobuf Type
  }

  type(schemaId) {
    if (!this.types.has(schemaId)) {
      const schema = this.schemas.get(schemaId);
      if (schema === undefined || schema.encoding !== "protobuf") {
        throw new Error(`schema ${schemaId} is not a protobuf schema`);
      }
      const set = descriptor.FileDescriptorSet.decode(schema.data);
      const root = protobuf.Root.fromDescriptor(set);
      this.types.set(schemaId, root.lookupType(schema.name));
    }
    return this.types.get(schemaId);
  }

  message(record) {
    const channel = this.channels.get(record.channelId);
    const type = this.type(channel.schemaId);
    const decoded = type.toObject(type.decode(record.data), { longs: String });
    return [channel.topic, [record.sequence, record.logTime.toString(), plain(decoded)]];
  }
}

function add(messages, [topic, row]) {
  (messages[topic] ??= []).push(row);
}

async function readIndexed(path) {
  const handle = await fs.promises.open(path, "r");
  try {
    const readable = {
      size: async () => BigInt((await handle.stat()).size),
      read: async (offset, length) => {
        const buffer = new Uint8Array(Number(length));
        const { bytesRead } = await handle.read(buffer, 0, buffer.length, Number(offset));
        if (bytesRead !== buffer.length) throw new Error(`short read at ${offset}`);
        return buffer;
      },
    };
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
    const decoders = new Decoders();
    for (const [id, schema] of reader.schemasById) decoders.schemas.set(id, schema);
    for (const [id, channel] of reader.channelsById) decoders.channels.set(id, channel);
    const metadata = {};
    for await (const record of reader.readMetadata()) metadata[record.name] = Object.fromEntries(record.metadata);
    const messages = {};
    for await (const record of reader.readMessages({ validateCrcs: true })) add(messages, decoders.message(record));
    // as a Foxglove panel reads: one topic at a time, forwards and (to find the latest) backwards
    const byTopic = {};
    for (const topic of Object.keys(messages)) {
      const sequences = [];
      for (const reverse of [false, true]) {
        const seen = [];
        for await (const record of reader.readMessages({ topics: [topic], reverse })) seen.push(record.sequence);
        sequences.push(reverse ? seen.reverse() : seen);
      }
      byTopic[topic] = sequences;
    }
    return { metadata, messages, byTopic, complete: true };
  } finally {
    await handle.close();
  }
}

function readStream(path) {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(fs.readFileSync(path));
  const decoders = new Decoders();
  const metadata = {};
  const messages = {};
  let record;
  while ((record = reader.nextRecord()) !== undefined) {
    if (record.type === "Schema") decoders.schemas.set(record.id, record);
    else if (record.type === "Channel") decoders.channels.set(record.id, record);
    else if (record.type === "Metadata") metadata[record.name] = Object.fromEntries(record.metadata);
    else if (record.type === "Message") add(messages, decoders.message(record));
  }
  return { metadata, messages, complete: reader.done() };
}

async function main() {
  const path = process.argv[2];
  if (path === undefined) {
    process.stderr.write("usage: node read_log.js FILE\n");
    process.exit(2);
  }
  const out = {};
  for (const [name, read] of [
    ["indexed", readIndexed],
    ["stream", readStream],
  ]) {
    try {
      out[name] = await read(path);
    } catch (error) {
      out[name] = { error: String(error && error.message ? error.message : error) };
    }
  }
  process.stdout.write(JSON.stringify(out));
}

main();
