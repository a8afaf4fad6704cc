// tsog-stream web player: the files of a bundled chunk (.sog), read from its central directory.
// Chunks have no comment and the end record last; entries are stored, or deflated (meta.json
// since spec 0.4: docs/spec.md section 1), which the engine's own reader also inflates.

const EOCD = 0x06054b50;
const CENTRAL = 0x02014b50;
const LOCAL = 0x04034b50;
const EOCD_SIZE = 22;

const STORED = 0;
const DEFLATED = 8;

/** The inflated bytes of a raw-deflate entry, checked against the size its record declares. */
async function inflate(bytes, size, name) {
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate-raw'));
    const out = new Uint8Array(await new Response(stream).arrayBuffer());
    if (out.byteLength !== size) throw new Error(`chunk entry ${name} inflates to ${out.byteLength} bytes, not ${size}`);
    return out;
}

/** name -> Uint8Array of each entry of the zip in `buffer` (an ArrayBuffer): stored entries
 *  are views into it, deflated ones are inflated. */
export async function readZip(buffer) {
    const view = new DataView(buffer);
    const fail = (what) => { throw new Error(`chunk is not a readable zip: ${what}`); };
    if (buffer.byteLength < EOCD_SIZE) fail('too short');
    const end = buffer.byteLength - EOCD_SIZE;
    if (view.getUint32(end, true) !== EOCD) fail('no end record at the end');
    const count = view.getUint16(end + 10, true);
    let at = view.getUint32(end + 16, true);
    const files = new Map();
    const names = new TextDecoder();
    for (let i = 0; i < count; i++) {
        if (at + 46 > end || view.getUint32(at, true) !== CENTRAL) fail(`central record ${i}`);
        const method = view.getUint16(at + 10, true);
        const packed = view.getUint32(at + 20, true);
        const size = view.getUint32(at + 24, true);
        const nameLength = view.getUint16(at + 28, true);
        const skip = nameLength + view.getUint16(at + 30, true) + view.getUint16(at + 32, true);
        const local = view.getUint32(at + 42, true);
        const name = names.decode(new Uint8Array(buffer, at + 46, nameLength));
        if (method !== STORED && method !== DEFLATED) fail(`${name} uses method ${method}`);
        if (local + 30 > end || view.getUint32(local, true) !== LOCAL) fail(`local header of ${name}`);
        const data = local + 30 + view.getUint16(local + 26, true) + view.getUint16(local + 28, true);
        if (data + packed > end) fail(`${name} runs past the end`);
        const bytes = new Uint8Array(buffer, data, packed);
        if (method === STORED && packed !== size) fail(`${name} is stored with two sizes`);
        files.set(name, method === STORED ? bytes : await inflate(bytes, size, name));
        at += 46 + skip;
    }
    return files;
}
