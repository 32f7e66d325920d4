// The Privzone phone's side of the Bluetooth protocol, in node, for the tests of
// reconciler/privzone (tests/unit/test_privzone_framing.py runs it).
//
// Written for these tests from how Privzone's frontend/src/components/MapPage.js behaves
// (read, not copied), keeping every step that decides whether a message gets through:
//
//   receive  stdin: one notification a line, as hex. Each notification is decoded on its
//            own with a fresh TextDecoder (a UTF-8 sequence split between two notifications
//            becomes U+FFFD on both sides), the strings are concatenated, and when a
//            notification's last byte is 0 the text so far, without its last character,
//            is the message: JSON.parse, the keys type, length and contents, and
//            `length == contents.length` (UTF-16 units). stdout: one JSON line a message,
//            {"type", "contents", "parsed"} or {"error"}, then {"pending"} if text is left.
//   send     stdin: one JSON line a message, {"type", "contents": <any JSON value>} built
//            as the phone builds it (contents = JSON.stringify(value), length =
//            contents.length), or {"body": "<text>"} sent as it is. The text is cut in
//            slices of 500 JavaScript characters (UTF-16 units: a surrogate pair can be
//            cut), each slice written as TextEncoder's bytes, then a write of one NUL.
//            stdout: one write a line, as hex.
"use strict";

const MAX_SLICE = 500;

function readStdin() {
  return new Promise((resolve) => {
    const parts = [];
    process.stdin.on("data", (part) => parts.push(part));
    process.stdin.on("end", () => resolve(Buffer.concat(parts).toString("utf8")));
  });
}

function lines(text) {
  return text.split("\n").map((line) => line.trim()).filter((line) => line.length > 0);
}

function checkMessage(message) {
  let input;
  try {
    input = JSON.parse(message);
  } catch (e) {
    return { error: "Json parsing issue" };
  }
  for (const key of ["type", "length", "contents"]) {
    if (input === null || typeof input !== "object" || !input.hasOwnProperty(key)) {
      return { error: "Json missing '" + key + "' key" };
    }
  }
  if (input["length"] != input["contents"].length) {
    return { error: "Json length mismatch", announced: input["length"],
             counted: input["contents"].length };
  }
  let parsed = null;
  try {
    parsed = JSON.parse(input["contents"]);
  } catch (e) {
    return { error: "contents are not JSON" };
  }
  return { type: input["type"], contents: input["contents"], parsed: parsed };
}

function receive(text) {
  let buffer = "";
  const out = [];
  for (const line of lines(text)) {
    const value = new Uint8Array(Buffer.from(line, "hex"));
    buffer = buffer.concat(new TextDecoder().decode(value));
    if (value.length > 0 && value[value.length - 1] === 0) {
      const message = buffer.slice(0, buffer.length - 1);
      buffer = "";
      out.push(checkMessage(message));
    }
  }
  if (buffer.length > 0) {
    out.push({ pending: buffer });
  }
  return out.map((item) => JSON.stringify(item)).join("\n");
}

function writesOf(buffer, writes) {
  writes.push(new TextEncoder().encode(buffer.slice(0, MAX_SLICE)));
  if (buffer.length > MAX_SLICE) {
    writesOf(buffer.slice(MAX_SLICE), writes);
  } else {
    writes.push(new Uint8Array([0]));
  }
}

function send(text) {
  const writes = [];
  for (const line of lines(text)) {
    const request = JSON.parse(line);
    let body = request["body"];
    if (body === undefined) {
      const contents = JSON.stringify(request["contents"]);
      body = JSON.stringify({ type: request["type"], contents: contents,
                              length: contents.length });
    }
    writesOf(body, writes);
  }
  return writes.map((write) => Buffer.from(write).toString("hex")).join("\n");
}

async function main() {
  const mode = process.argv[2];
  const input = await readStdin();
  if (mode === "receive") {
    process.stdout.write(receive(input) + "\n");
  } else if (mode === "send") {
    process.stdout.write(send(input) + "\n");
  } else {
    process.stderr.write("usage: node privzone_phone.js receive|send < input\n");
    process.exit(2);
  }
}

main();
