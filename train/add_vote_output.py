"""Expose the RGB-D model's centre votes as an ONNX output `votes` [1,V,3,H/2,W/2], the graph otherwise
untouched (depth, gaussians and embeddings stay bit-identical). The node splits a window instance
whose votes form separate clumps (node/src/group/votes.rs).

The vote is the tensor the instance head feeds its Fourier features (`vote = x_half[:, 3:6] +
embeddings[:, :3]` in gf/model.py): the one Add whose output goes to a Concat and to the Mul of
every frequency. export_recon.py adds it to models with centre votes; files exported before are
rewritten (their manifest then needs MANIFEST_OUTPUT below):

  train/.venv/bin/python train/add_vote_output.py models/groupforward-mini-rgbd.onnx
"""

import argparse

import onnx


def vote_tensor(graph):
    """The name of the vote tensor: the Add feeding a Concat and at least three Mul nodes."""
    users = {}
    for node in graph.node:
        for name in node.input:
            users.setdefault(name, []).append(node.op_type)
    found = [n.output[0] for n in graph.node if n.op_type == 'Add'
             and 'Concat' in users.get(n.output[0], []) and users[n.output[0]].count('Mul') >= 3]
    if len(found) != 1:
        raise SystemExit(f'expected one vote tensor, found {found}')
    return found[0]


def add_votes(path):
    """Add the `votes` output to the ONNX file `path` in place; False when it already has one."""
    model = onnx.load(path)
    graph = model.graph
    if any(o.name == 'votes' for o in graph.output):
        return False
    vote = vote_tensor(graph)
    graph.initializer.append(onnx.helper.make_tensor('votes_axes', onnx.TensorProto.INT64, [1], [0]))
    # The graph folds (batch, views) into one axis; batch is 1, so unsqueezing restores [1,V,...].
    graph.node.append(onnx.helper.make_node('Unsqueeze', [vote, 'votes_axes'], ['votes'], name='votes_out'))
    graph.output.append(onnx.helper.make_tensor_value_info('votes', onnx.TensorProto.FLOAT, [1, 'V', 3, 'Hv', 'Wv']))
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return True


# The manifest's entry for the output (export_recon.py writes it for models with centre votes).
MANIFEST_OUTPUT = """
# The instance head's centre votes at half resolution (added by train/add_vote_output.py; the
# other outputs are unchanged): the node splits an instance whose votes form separate clumps.
[[outputs]]
name = "votes"
shape = [1, "V", 3, "Hv", "Wv"]
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('model', help='an RGB-D .onnx, rewritten in place')
    args = parser.parse_args()
    if add_votes(args.model):
        print(f'{args.model}: `votes` added')
    else:
        print(f'{args.model} already has `votes`')


if __name__ == '__main__':
    main()
