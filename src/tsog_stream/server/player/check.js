// tsog-stream web player: what the page accepts from a manifest before it uses any of it. A
// manifest may come from any origin (/play/?manifest=URL), so every field the page turns into
// a URL, a size, a loop bound or a camera is checked first, with the schema's own rules
// (tsog_stream/schemas/manifest.py): a chunk's file is chunks/NNNNNN.sog beside the manifest,
// never another path or host. A manifest that breaks one is refused whole, naming the field.

const CHUNK_FILE = /^chunks\/[0-9]{6}\.sog$/; // schemas/manifest.py _CHUNK_FILE
const SHA256 = /^[0-9a-f]{64}$/;
/** The largest manifest read (container/index.py MAX_INDEX_BYTES). */
export const MAX_MANIFEST_BYTES = 64 << 20;
/** The largest chunk the page fetches: its bytes are held whole in memory. */
export const MAX_CHUNK_BYTES = 1 << 30;
const MAX_LEVEL = 62; // 2 ** level windows stays exact in a double
const MAX_COUNT = 2 ** 32; // Gaussians in one chunk, at most
const MAX_OFFSET = Number.MAX_SAFE_INTEGER;
const SHOWN = 60; // characters of a refused value quoted in the message

class Refused extends Error {}

/** A value quoted in a message: JSON, cut short (the page shows it as text). */
function quoted(value) {
    const text = JSON.stringify(value) ?? String(value);
    return text.length > SHOWN ? `${text.slice(0, SHOWN)}...` : text;
}

function refuse(where, what, value) {
    throw new Refused(`${where} ${what} (found ${quoted(value)})`);
}

function integer(value, where, max = MAX_OFFSET) {
    if (!Number.isSafeInteger(value) || value < 0 || value > max) refuse(where, `must be a whole number from 0 to ${max}`, value);
    return value;
}

function finite(value, where) {
    if (typeof value !== 'number' || !Number.isFinite(value)) refuse(where, 'must be a finite number', value);
    return value;
}

function list(value, where) {
    if (!Array.isArray(value)) refuse(where, 'must be a list', value);
    return value;
}

function object(value, where) {
    if (value === null || typeof value !== 'object' || Array.isArray(value)) refuse(where, 'must be an object', value);
    return value;
}

function vector(value, where, length) {
    list(value, where);
    if (value.length !== length) refuse(where, `must hold ${length} numbers`, value);
    value.forEach((v, i) => finite(v, `${where}[${i}]`));
}

function checkScene(scene) {
    object(scene, 'scene');
    finite(scene.start_s, 'scene.start_s');
    finite(scene.end_s, 'scene.end_s');
    if (scene.end_s < scene.start_s) refuse('scene.end_s', 'is before start_s', scene.end_s);
    if (scene.fps != null && !(finite(scene.fps, 'scene.fps') > 0)) refuse('scene.fps', 'must be positive', scene.fps);
    if (![null, undefined, 0, 1, 2].includes(scene.timeline_type)) refuse('scene.timeline_type', 'must be null, 0, 1 or 2', scene.timeline_type);
    if (scene.duration_assumed != null && typeof scene.duration_assumed !== 'boolean') {
        refuse('scene.duration_assumed', 'must be true or false', scene.duration_assumed);
    }
    object(scene.bbox, 'scene.bbox');
    vector(scene.bbox.min, 'scene.bbox.min', 3);
    vector(scene.bbox.max, 'scene.bbox.max', 3);
    if (scene.core != null) {
        object(scene.core, 'scene.core');
        vector(scene.core.center, 'scene.core.center', 3);
        if (!(finite(scene.core.radius, 'scene.core.radius') >= 0)) refuse('scene.core.radius', 'must not be negative', scene.core.radius);
    }
}

function checkCamera(camera, where) {
    object(camera, where);
    vector(camera.position, `${where}.position`, 3);
    list(camera.rotation, `${where}.rotation`);
    if (camera.rotation.length !== 3) refuse(`${where}.rotation`, 'must hold 3 rows', camera.rotation);
    camera.rotation.forEach((row, i) => vector(row, `${where}.rotation[${i}]`, 3));
    for (const key of ['fy', 'height']) {
        if (!(finite(camera[key], `${where}.${key}`) > 0)) refuse(`${where}.${key}`, 'must be positive', camera[key]);
    }
    if (camera.name != null && typeof camera.name !== 'string') refuse(`${where}.name`, 'must be text', camera.name);
}

function checkChunk(c, i, layerCount) {
    const where = `chunks[${i}]`;
    object(c, where);
    if (c.id !== i) refuse(`${where}.id`, `must be ${i}`, c.id);
    if (typeof c.file !== 'string' || !CHUNK_FILE.test(c.file)) refuse(`${where}.file`, 'is not chunks/NNNNNN.sog', c.file);
    if (typeof c.sha256 !== 'string' || !SHA256.test(c.sha256)) refuse(`${where}.sha256`, 'is not 64 hex digits', c.sha256);
    integer(c.offset, `${where}.offset`);
    integer(c.length, `${where}.length`, MAX_CHUNK_BYTES);
    integer(c.count, `${where}.count`, MAX_COUNT);
    integer(c.level, `${where}.level`, MAX_LEVEL);
    integer(c.node, `${where}.node`);
    finite(c.start_s, `${where}.start_s`);
    finite(c.end_s, `${where}.end_s`);
    if (c.layer != null) integer(c.layer, `${where}.layer`, layerCount - 1);
    if (c.sh_of != null && integer(c.sh_of, `${where}.sh_of`) >= i) refuse(`${where}.sh_of`, 'must name an earlier chunk', c.sh_of);
}

function checkNode(n, j, chunkCount) {
    const where = `nodes[${j}]`;
    object(n, where);
    integer(n.level, `${where}.level`, MAX_LEVEL);
    integer(n.index, `${where}.index`);
    list(n.chunks, `${where}.chunks`).forEach((id, k) => integer(id, `${where}.chunks[${k}]`, chunkCount - 1));
}

/** Throw an Error saying which field of `m` the page refuses, or return `m` unchanged. */
export function checkManifest(m) {
    try {
        object(m, 'the manifest');
        if (m.format !== 'tsogs') refuse('format', 'is not "tsogs": not a TSOG stream manifest', m.format);
        if (!(finite(m.window_s, 'window_s') > 0)) refuse('window_s', 'must be positive', m.window_s);
        checkScene(m.scene);
        const layers = m.layers == null ? [] : list(m.layers, 'layers');
        layers.forEach((layer, i) => {
            object(layer, `layers[${i}]`);
            if (layer.index !== i) refuse(`layers[${i}].index`, `must be ${i}`, layer.index);
            if (layer.psnr_db != null) finite(layer.psnr_db, `layers[${i}].psnr_db`);
        });
        list(m.chunks, 'chunks').forEach((c, i) => checkChunk(c, i, Math.max(layers.length, 1)));
        list(m.nodes, 'nodes').forEach((n, j) => checkNode(n, j, m.chunks.length));
        if (m.cameras != null) list(m.cameras, 'cameras').forEach((c, i) => checkCamera(c, `cameras[${i}]`));
        if (m.view != null) checkCamera(m.view, 'view');
        if (m.live != null) checkLive(m.live, m.nodes.filter((n) => n.level === 0).length);
    } catch (err) {
        if (err instanceof Refused) throw new Error(`manifest refused: ${err.message}`);
        throw err;
    }
    return m;
}

/** A live stream's publication (docs/spec.md section 8.8): one time entry per window. */
function checkLive(live, windows) {
    object(live, 'live');
    integer(live.sequence, 'live.sequence');
    if (typeof live.ended !== 'boolean') refuse('live.ended', 'must be true or false', live.ended);
    const times = list(live.windows, 'live.windows');
    if (times.length !== windows) refuse('live.windows', `must have one entry per window (${windows})`, times.length);
    times.forEach((w, i) => {
        object(w, `live.windows[${i}]`);
        finite(w.arrived_s, `live.windows[${i}].arrived_s`);
        finite(w.published_s, `live.windows[${i}].published_s`);
    });
}

/** The body of `response` as an ArrayBuffer, refused with the message `tooLong` as soon as it
 * is past `limit` bytes (nothing beyond that is held). */
export async function readCapped(response, limit, tooLong) {
    if (Number(response.headers.get('content-length')) > limit) throw new Error(tooLong);
    if (!response.body) return response.arrayBuffer();
    const reader = response.body.getReader();
    const parts = [];
    let size = 0;
    for (;;) {
        const { done, value } = await reader.read();
        if (done) break;
        size += value.byteLength;
        if (size > limit) {
            reader.cancel();
            throw new Error(tooLong);
        }
        parts.push(value);
    }
    const out = new Uint8Array(size);
    let at = 0;
    for (const part of parts) {
        out.set(part, at);
        at += part.byteLength;
    }
    return out.buffer;
}
