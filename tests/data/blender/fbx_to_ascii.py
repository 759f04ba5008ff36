# Writes a binary FBX 7.x file as FBX ASCII text (the layout the FBX SDK
# writes: "Name: value, value {" ... "}", strings quoted, a binary name
# "Name\x00\x01Class" as "Class::Name", arrays as "*count { a: ... }").
# Used to make the tests' ASCII twin of a Blender export:
#   cd tests/data/blender && python3 fbx_to_ascii.py two_cameras.fbx two_cameras_ascii.fbx
import base64
import struct
import sys
import zlib


def read_records(b, at, end, wide, depth=0):
    nodes = []
    head = 25 if wide else 13
    while at < end:
        if wide:
            end_offset, count, list_len = struct.unpack_from('<QQQ', b, at)
            name_len = b[at + 24]
        else:
            end_offset, count, list_len = struct.unpack_from('<III', b, at)
            name_len = b[at + 12]
        if end_offset == 0:
            return nodes, at + head
        name = b[at + head:at + head + name_len].decode()
        p = at + head + name_len
        props = []
        for _ in range(count):
            t = chr(b[p])
            p += 1
            if t in 'YCILFD':
                fmt = {'Y': '<h', 'C': '<B', 'I': '<i', 'L': '<q', 'F': '<f', 'D': '<d'}[t]
                props.append((t, struct.unpack_from(fmt, b, p)[0]))
                p += struct.calcsize(fmt)
            elif t in 'SR':
                (n,) = struct.unpack_from('<I', b, p)
                props.append((t, b[p + 4:p + 4 + n]))
                p += 4 + n
            elif t in 'fdlib':
                n, enc, stored = struct.unpack_from('<III', b, p)
                raw = b[p + 12:p + 12 + stored]
                if enc == 1:
                    raw = zlib.decompress(raw)
                fmt = {'f': 'f', 'd': 'd', 'l': 'q', 'i': 'i', 'b': 'B'}[t]
                props.append(('*', list(struct.unpack('<%d%s' % (n, fmt), raw))))
                p += 12 + stored
            else:
                raise ValueError('property type %r' % t)
        children = []
        if p < end_offset:
            children, _ = read_records(b, p, end_offset, wide, depth + 1)
        nodes.append((name, props, children))
        at = end_offset
    return nodes, at


def text(v):
    if b'\x00\x01' in v:
        name, cls = v.split(b'\x00\x01', 1)
        v = cls + b'::' + name
    return '"' + v.decode('utf-8', 'replace').replace('"', '&quot;') + '"'


def number(t, v):
    if t in 'FD' or isinstance(v, float):
        return repr(float(v))
    return str(int(v))


def write(out, nodes, indent):
    for name, props, children in nodes:
        values = []
        arrays = []
        for t, v in props:
            if t == 'S':
                values.append(text(v))
            elif t == 'R':
                values.append('"' + base64.b64encode(v).decode() + '"')
            elif t == 'C':
                values.append('T' if v else 'F')
            elif t == '*':
                values.append('*%d' % len(v))
                arrays.append(v)
            else:
                values.append(number(t, v))
        out.write('\t' * indent + name + ': ' + ', '.join(values))
        if arrays:
            out.write(' {\n' + '\t' * (indent + 1) + 'a: ' +
                      ','.join(number('D' if isinstance(x, float) else 'L', x) for x in arrays[0]) +
                      '\n' + '\t' * indent + '}\n')
        elif children:
            out.write(' {\n')
            write(out, children, indent + 1)
            out.write('\t' * indent + '}\n')
        else:
            out.write('\n')


def main():
    b = open(sys.argv[1], 'rb').read()
    assert b.startswith(b'Kaydara FBX Binary  \x00'), 'not a binary FBX file'
    (version,) = struct.unpack_from('<I', b, 23)
    nodes, _ = read_records(b, 27, len(b), version >= 7500)
    with open(sys.argv[2], 'w') as out:
        out.write('; FBX %d.%d.0 project file\n' % (version // 1000, version // 100 % 10))
        out.write('; converted from the binary file by fbx_to_ascii.py\n\n')
        write(out, nodes, 0)


main()
