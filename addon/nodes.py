"""Node wiring shared by the materials and the splats' geometry nodes: math nodes fed by numbers or sockets."""


class Nodes:
    """Math nodes with float or socket inputs, laid out in columns of 12 from ``(x, y)``.

    ``n.math("MULTIPLY", a, b)`` returns the new node's output socket; an input
    that is a socket is linked, a number is set as the input's value.
    """

    def __init__(self, tree, x=-3000, y=0):
        self.tree, self.x, self.y, self.n = tree, x, y, 0

    def _place(self, node, label=None, loc=None):
        node.location = loc if loc is not None else (self.x + 160 * (self.n // 12), self.y - 120 * (self.n % 12))
        self.n += 1
        if label:
            node.label = label
        return node

    def _set(self, sock, value):
        if hasattr(value, "is_output"):
            self.tree.links.new(value, sock)
        elif isinstance(value, (tuple, list)):
            sock.default_value = value
        else:
            sock.default_value = float(value)

    def math(self, op, a, b=0.0, c=None, label=None, loc=None):
        node = self._place(self.tree.nodes.new("ShaderNodeMath"), label, loc)
        node.operation = op
        for sock, v in zip(node.inputs, (a, b, c)):
            if v is not None:
                self._set(sock, v)
        return node.outputs[0]

    def vmath(self, op, a, b=None, label=None, loc=None):
        node = self._place(self.tree.nodes.new("ShaderNodeVectorMath"), label, loc)
        node.operation = op
        self._set(node.inputs[0], a)
        if b is not None:
            self._set(node.inputs[1], b)
        return node.outputs["Value" if op in ("DOT_PRODUCT", "LENGTH", "DISTANCE") else "Vector"]

    def map_range(self, x, a, b, c=0.0, d=1.0, label=None):
        """Clamped linear ``(x − a) / (b − a)`` onto ``c..d``."""
        node = self._place(self.tree.nodes.new("ShaderNodeMapRange"), label)
        node.data_type, node.interpolation_type, node.clamp = "FLOAT", "LINEAR", True
        for name, v in (("Value", x), ("From Min", a), ("From Max", b), ("To Min", c), ("To Max", d)):
            self._set(node.inputs[name], v)
        return node.outputs["Result"]

    def add_all(self, terms, label=None):
        total = terms[0]
        for t in terms[1:]:
            total = self.math("ADD", total, t, label=label)
        return total


__all__ = ["Nodes"]
