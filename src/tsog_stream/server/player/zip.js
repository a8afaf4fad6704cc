// tsog-stream web player: the files of a bundled chunk (.sog), read from its central directory.
// Chunks have no comment and the end record last; entries are stored, or deflated (meta.json
// since spec 0.4: docs/spec.md section 1), which the engine's own reader also inflates.

const EOCD = 0x06054b50;
const CENTRAL = 0x02014b50;
const LOCAL = 0x04034b50;
const EOCD_SIZE = 22;

const STORED = 0;
const DEFLATED = 8;

/** Deflate's own ceiling on expansion (as codec/bundle.py): a larger declared size is a lie. */
const MAX_DEFLATE_RATIO = 1032;

/** The inflated bytes of a raw-deflate entry, exactly the size its record declares: that size
 * is checked against deflate's ceiling before anything is allocated, and inflating stops as
 * soon as it would pass it, so a hostile chunk cannot make the page hold more. */
async function inflate(bytes, size, name) {
    if (size > MAX_DEFLATE_RATIO * bytes.byteLength + 1024) {
        throw new Error(`chunk entry ${name} declares ${size} bytes from ${bytes.byteLength}`);
    }
    const reader = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate-raw')).getReader();
    const out = new Uint8Array(size);
    let at = 0;
    for (;;) {
        const { done, value } = await reader.read();
        if (done) break;
        if (at + value.byteLength > size) {
            await reader.cancel();
            throw new Error(`chunk entry ${name} inflates to more than ${size} bytes`);
        }
        out.set(value, at);
        at += value.byteLength;
    }
    if (at !== size) throw new Error(`chunk entry ${name} inflates to ${at} bytes, not ${size}`);
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

/** CRC-32 (the zip polynomial) lookup table, built once. */
const CRC_TABLE = (() => {
    const table = new Uint32Array(256);
    for (let n = 0; n < 256; n++) {
        let c = n;
        for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
        table[n] = c >>> 0;
    }
    return table;
})();

function crc32(bytes) {
    let c = 0xffffffff;
    for (let i = 0; i < bytes.length; i++) c = CRC_TABLE[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
    return (c ^ 0xffffffff) >>> 0;
}

/** An ArrayBuffer holding a zip of `files` (name -> Uint8Array, in the Map's order), every
 * entry stored: how the page hands the engine a chunk it has put together itself. */
export function writeZip(files) {
    const names = new TextEncoder();
    const entries = [...files].map(([name, bytes]) => ({ name: names.encode(name), bytes, crc: crc32(bytes) }));
    const size = entries.reduce((n, e) => n + 30 + e.name.length + e.bytes.length + 46 + e.name.length, EOCD_SIZE);
    const buffer = new ArrayBuffer(size);
    const view = new DataView(buffer);
    const out = new Uint8Array(buffer);
    let at = 0;
    const header = (magic, e, central, offset) => {
        view.setUint32(at, magic, true);
        const fields = central ? at + 6 : at + 4; // a central record has "made by" first
        view.setUint16(fields, 20, true); // version needed
        view.setUint16(fields + 2, 0, true); // flags
        view.setUint16(fields + 4, STORED, true);
        view.setUint16(fields + 6, 0, true); // time
        view.setUint16(fields + 8, 0x21, true); // date: 1980-01-01
        view.setUint32(fields + 10, e.crc, true);
        view.setUint32(fields + 14, e.bytes.length, true);
        view.setUint32(fields + 18, e.bytes.length, true);
        view.setUint16(fields + 22, e.name.length, true);
        view.setUint16(fields + 24, 0, true); // extra field
        if (central) {
            view.setUint16(at + 4, 20, true); // made by
            view.setUint32(at + 42, offset, true);
            out.set(e.name, at + 46);
            at += 46 + e.name.length;
        } else {
            out.set(e.name, at + 30);
            at += 30 + e.name.length;
        }
    };
    const offsets = [];
    for (const e of entries) {
        offsets.push(at);
        header(LOCAL, e, false, 0);
        out.set(e.bytes, at);
        at += e.bytes.length;
    }
    const central = at;
    entries.forEach((e, i) => header(CENTRAL, e, true, offsets[i]));
    view.setUint32(at, EOCD, true);
    view.setUint16(at + 8, entries.length, true);
    view.setUint16(at + 10, entries.length, true);
    view.setUint32(at + 12, at - central, true);
    view.setUint32(at + 16, central, true);
    return buffer;
}
