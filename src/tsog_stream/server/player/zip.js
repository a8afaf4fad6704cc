// tsog-stream web player: the files of a bundled chunk (.sog), read from its central directory.
// Chunks are written with stored entries, no comment and the end record last (docs/spec.md
// section 1), which is also what the engine's own reader requires.

const EOCD = 0x06054b50;
const CENTRAL = 0x02014b50;
const LOCAL = 0x04034b50;
const EOCD_SIZE = 22;

/** name -> Uint8Array view of each stored entry of the zip in `buffer` (an ArrayBuffer). */
export function readZip(buffer) {
    const view = new DataView(buffer);
    const fail = (what) => { throw new Error(`chunk is not a stored zip: ${what}`); };
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
        const size = view.getUint32(at + 20, true);
        const nameLength = view.getUint16(at + 28, true);
        const skip = nameLength + view.getUint16(at + 30, true) + view.getUint16(at + 32, true);
        const local = view.getUint32(at + 42, true);
        const name = names.decode(new Uint8Array(buffer, at + 46, nameLength));
        if (method !== 0) fail(`${name} is compressed (method ${method})`);
        if (local + 30 > end || view.getUint32(local, true) !== LOCAL) fail(`local header of ${name}`);
        const data = local + 30 + view.getUint16(local + 26, true) + view.getUint16(local + 28, true);
        if (data + size > end) fail(`${name} runs past the end`);
        files.set(name, new Uint8Array(buffer, data, size));
        at += 46 + skip;
    }
    return files;
}
