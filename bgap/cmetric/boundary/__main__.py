from bgap.runner.numerics import command

main = command("bgap.commands.cmetric_boundary")
if __name__ == "__main__":
    main()
