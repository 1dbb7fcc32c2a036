// Independent check of an MCAP trace: read it with @mcap/core's McapIndexedReader
// (summary read through the footer, chunk CRCs validated while reading; the data
// section CRC of the Data End record is checked here too) and decode every message
// with protobufjs from the FileDescriptorSet stored as the channel's schema.
//
// Usage: node check_mcap.mjs FILE.mcap [--json]
// Exit 0 when every message decodes and every CRC matches; 1 otherwise.
import { open } from "node:fs/promises";
import { crc32 } from "node:zlib";
import { McapIndexedReader } from "@mcap/core";
import { decompress } from "fzstd";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const args = process.argv.slice(2);
const json = args.includes("--json");
const file = args.find((a) => !a.startsWith("--"));
if (!file) {
  console.error("usage: node check_mcap.mjs FILE.mcap [--json]");
  process.exit(2);
}

const handle = await open(file, "r");
const size = BigInt((await handle.stat()).size);
const readable = {
  size: async () => size,
  read: async (offset, length) => {
    const buffer = new Uint8Array(Number(length));
    await handle.read(buffer, 0, Number(length), Number(offset));
    return buffer;
  },
};

const report = { file, library: "", messages: 0, chunks: 0, topics: {}, errors: [] };
try {
  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: { zstd: (data, size) => decompress(data, new Uint8Array(Number(size))) },
  });
  report.library = reader.header.library;
  report.chunks = reader.chunkIndexes.length;
  // data section CRC: every byte from the start of the file to the Data End record
  if (reader.dataSectionCrc !== undefined && reader.dataSectionCrc !== 0) {
    const data = await readable.read(0n, reader.dataEndOffset);
    const actual = crc32(data) >>> 0;
    report.data_section_crc = actual === reader.dataSectionCrc ? "ok" : "mismatch";
    if (actual !== reader.dataSectionCrc) report.errors.push("data section CRC mismatch");
  } else {
    report.data_section_crc = "absent";
  }
  const types = new Map(); // schema id -> protobufjs Type
  for (const [id, schema] of reader.schemasById) {
    if (schema.encoding !== "protobuf") continue;
    const set = descriptor.FileDescriptorSet.decode(schema.data);
    const root = protobuf.Root.fromDescriptor(set);
    types.set(id, root.lookupType(schema.name));
  }
  for await (const message of reader.readMessages({ validateCrcs: true })) {
    const channel = reader.channelsById.get(message.channelId);
    const type = types.get(channel.schemaId);
    const entry = (report.topics[channel.topic] ??= {
      schema: reader.schemasById.get(channel.schemaId).name, count: 0, first: null,
    });
    entry.count += 1;
    report.messages += 1;
    if (type === undefined) continue;
    try {
      const decoded = type.decode(message.data);
      if (entry.first === null) {
        entry.first = type.toObject(decoded, { longs: String, defaults: true });
      }
    } catch (error) {
      report.errors.push(`${channel.topic} at ${message.logTime}: ${error.message}`);
    }
  }
  const expected = reader.statistics ? Number(reader.statistics.messageCount) : null;
  report.statistics_messages = expected;
  if (expected !== null && expected !== report.messages) {
    report.errors.push(`statistics list ${expected} messages, ${report.messages} read`);
  }
} catch (error) {
  report.errors.push(String(error && error.message ? error.message : error));
} finally {
  await handle.close();
}

if (json) {
  console.log(JSON.stringify(report));
} else {
  console.log(`${file}: library ${report.library}; ${report.chunks} chunks, ` +
    `${report.messages} messages on ${Object.keys(report.topics).length} topics ` +
    `decoded with protobufjs; chunk CRCs validated, data section CRC ` +
    `${report.data_section_crc}`);
  for (const [topic, entry] of Object.entries(report.topics)) {
    console.log(`  ${topic}  ${entry.schema}  ${entry.count}`);
  }
  for (const error of report.errors) console.log(`ERROR ${error}`);
}
// exitCode, not process.exit(): exit() would cut a large report written to a pipe
process.exitCode = report.errors.length ? 1 : 0;
